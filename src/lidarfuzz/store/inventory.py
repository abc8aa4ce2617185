"""The store's inventory: the data sets and systems under test that campaigns run on and
against, recorded with how to open or build them — what ``lidarfuzz datasets`` and
``lidarfuzz models`` and the web app's data-set and model pages call.

(The *operator catalogue*, :mod:`lidarfuzz.operators.catalogue`, is something else: it
describes the mutation operators.)"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from sqlalchemy import func, select

from lidarfuzz.io.options import DatasetOptions
from lidarfuzz.store.errors import ConflictError, NotFoundError
from lidarfuzz.store.models import Dataset, Model, Task
from lidarfuzz.store.store import Store, StoreError

if TYPE_CHECKING:
    from lidarfuzz.io.dataset import Dataset as OpenedDataset


def add_dataset(store: Store, name: str, path: str | PathLike[str], notes: str = "",
                options: DatasetOptions | None = None) -> Dataset:
    """Open the data at ``path`` (any supported source; it is validated, never modified) with
    ``options`` and record it with them, so every later opening reads it the same way."""
    from lidarfuzz.io.open import open_dataset

    source = Path(path).resolve()
    options = (options or DatasetOptions()).resolved()
    dataset = open_dataset(source, options=options)
    frames = len(dataset.frame_ids())
    if frames == 0:
        raise StoreError(f"{source}: no frames to test")
    dataset[dataset.frame_ids()[0]]  # a layout that does not fit fails now, not mid-campaign
    with store.session() as s:
        if s.scalar(select(Dataset).where(Dataset.name == name)) is not None:
            raise ConflictError(f"a data set called {name!r} exists already (lidarfuzz datasets list)")
        row = Dataset(name=name, path=str(source), format=dataset.format, frame_count=frames, notes=notes,
                      options=options.stored())
        s.add(row)
    return row


def dataset_options(row: Dataset) -> DatasetOptions:
    """The options a registered data set was recorded with."""
    return DatasetOptions.from_stored(row.options)


def open_registered(row: Dataset, **kwargs: Any) -> OpenedDataset[Any]:
    """Open a registered data set as it was recorded (its path, read with its options)."""
    from lidarfuzz.io.open import open_dataset

    return open_dataset(row.path, options=dataset_options(row), **kwargs)


def options_at(store: Store, path: str | PathLike[str]) -> DatasetOptions:
    """The options of the data set registered at ``path`` (the defaults when none is), for code
    that knows a data set only by its path (the web app's frame views)."""
    with store.session() as s:
        row = s.scalars(select(Dataset).where(Dataset.path == str(path)).order_by(Dataset.id)).first()
        return dataset_options(row) if row is not None else DatasetOptions()


def add_model(store: Store, name: str, spec: str, options: dict[str, Any] | None = None, notes: str = "", *,
              modality: str = "lidar") -> Model:
    """Build the system a spec names (so a bad spec fails now, not mid-campaign) and record it
    with its fingerprint; ``modality`` ``camera``: a steering system
    (:func:`~lidarfuzz.suts.registry.create_camera`)."""
    from lidarfuzz.suts.registry import create, create_camera

    system = (create_camera if modality == "camera" else create)(spec, **(options or {}))
    with store.session() as s:
        if s.scalar(select(Model).where(Model.name == name)) is not None:
            raise ConflictError(f"a model called {name!r} exists already (lidarfuzz models list)")
        row = Model(name=name, spec=spec, options=dict(options or {}), fingerprint=system.fingerprint(), notes=notes)
        s.add(row)
    return row


def _named(store: Store, table: type[Dataset] | type[Model], name: str, what: str, listing: str) -> Any:
    with store.session() as s:
        row = s.scalar(select(table).where(table.name == name))
        if row is None:
            raise NotFoundError(f"no {what} called {name!r} (lidarfuzz {listing} list)")
        return row


def get_dataset(store: Store, name: str) -> Dataset:
    """The data set recorded as ``name``."""
    return _named(store, Dataset, name, "data set", "datasets")


def get_model(store: Store, name: str) -> Model:
    """The system under test recorded as ``name``."""
    return _named(store, Model, name, "model", "models")


def list_datasets(store: Store) -> list[Dataset]:
    with store.session() as s:
        return list(s.scalars(select(Dataset).order_by(Dataset.name)))


def list_models(store: Store) -> list[Model]:
    with store.session() as s:
        return list(s.scalars(select(Model).order_by(Model.name)))


_Registered = TypeVar("_Registered", Dataset, Model)


def _remove(store: Store, table: type[_Registered], name: str, kind: str) -> None:
    with store.session() as s:
        row = s.scalar(select(table).where(table.name == name))
        if row is None:
            raise NotFoundError(f"no {kind} called {name!r}")
        column = Task.dataset_id if table is Dataset else Task.model_id
        used = s.scalar(select(func.count()).select_from(Task).where(column == row.id)) or 0
        if used:
            raise ConflictError(f"{kind} {name!r} is used by {used} task(s); delete those first")
        s.delete(row)


def remove_dataset(store: Store, name: str) -> None:
    """Forget a data set (its files are left alone)."""
    _remove(store, Dataset, name, "data set")


def remove_model(store: Store, name: str) -> None:
    _remove(store, Model, name, "model")
