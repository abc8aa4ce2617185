"""The campaign store: SQLAlchemy models, Alembic migrations, SQLite (WAL) or PostgreSQL."""

from lidarfuzz.store.models import Dataset, Finding, FrameResult, Model, Status, Subtask, SutOutput, Task
from lidarfuzz.store.store import Store, StoreError, store_url

__all__ = ["Dataset", "Finding", "FrameResult", "Model", "Status", "Store", "StoreError", "Subtask", "SutOutput",
           "Task", "store_url"]
