"""The store's inventory: the data sets and systems under test that campaigns run on and
against, recorded with how to open or build them — what ``lidarfuzz datasets`` and
``lidarfuzz models`` and the web app's data-set and model pages call.

(The *operator catalogue*, :mod:`lidarfuzz.operators.catalogue`, is something else: it
describes the mutation operators.)"""

from __future__ import annotations

import unicodedata
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from sqlalchemy import select

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.io.options import DatasetOptions
from lidarfuzz.store.errors import ConflictError, NotFoundError
from lidarfuzz.store.models import Dataset, Model, Task
from lidarfuzz.store.store import Store, StoreError

if TYPE_CHECKING:
    from lidarfuzz.io.dataset import Dataset as OpenedDataset


#: The longest name of a data set or model (characters)
NAME_LIMIT = 100
#: Characters that reorder or hide the text around them in a terminal (bidirectional embeddings,
#: overrides and isolates): escaped on output even in notes
BIDI_CONTROLS = frozenset("\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069")
#: Format characters that text needs (emoji sequences, Indic scripts): kept on output
JOINERS = frozenset("\u200c\u200d")


def _unsafe(char: str, *, notes: bool = False) -> bool:
    """Whether ``char`` can move a terminal's cursor, recolour, retitle or reorder what it shows:
    control characters (C0, DEL, C1), bidirectional controls, line and paragraph separators, and
    in a name also every other format character (zero-width ones). Notes keep tabs and line
    breaks (``\\n``; a form's ``\\r\\n`` is made ``\\n`` first) and format characters that text needs
    (a zero-width joiner inside an emoji)."""
    if notes and char in "\t\n":
        return False
    category = unicodedata.category(char)
    return category in ("Cc", "Zl", "Zp") or char in BIDI_CONTROLS or (not notes and category == "Cf")


def printable(text: str, *, newlines: bool = False) -> str:
    """``text`` safe to print to a terminal: every control and format character (bidirectional
    controls, zero-width spaces; not the joiners), line and paragraph separator shown as an escape
    (``\\x1b``, ``\\u202e``), a tab as a space; line breaks kept with ``newlines``. For names and
    notes stored before :func:`check_name` refused them.

    Example:
        >>> printable("evil" + chr(27) + "]0;pwned" + chr(7))
        'evil\\\\x1b]0;pwned\\\\x07'
    """
    out = []
    for char in text:
        if char == "\n" and newlines:
            out.append(char)
        elif char == "\t":
            out.append(" ")
        elif unicodedata.category(char) in ("Cc", "Cf", "Zl", "Zp") and char not in JOINERS:
            out.append(char.encode("unicode_escape").decode("ascii"))
        else:
            out.append(char)
    return "".join(out)


def check_name(name: str, field: str = "name") -> str:
    """``name`` if it can name a data set or model: 1 to :data:`NAME_LIMIT` characters, no control
    or format characters (they would reach terminals and pages), no path separator, not starting
    with a dot or a space; else a one-line error naming ``field``."""
    shown = f"'{printable(name[:NAME_LIMIT])}'" + ("..." if len(name) > NAME_LIMIT else "")
    bad = next((c for c in name if _unsafe(c)), None)
    if bad is not None:
        raise LidarfuzzError(f"{field}: {shown} holds the control character "
                             f"{bad.encode('unicode_escape').decode('ascii')}; use letters, digits, '.', '_', '-'")
    if not name.strip():
        raise LidarfuzzError(f"{field}: empty; give a name (letters, digits, '.', '_', '-')")
    if "/" in name or "\\" in name:
        raise LidarfuzzError(f"{field}: {shown} holds a path separator; a name is not a path")
    if name.startswith("."):
        raise LidarfuzzError(f"{field}: {shown} starts with a dot; start it with a letter or digit")
    if name != name.strip():
        raise LidarfuzzError(f"{field}: {shown} starts or ends with a space")
    if len(name) > NAME_LIMIT:
        raise LidarfuzzError(f"{field}: {shown} has {len(name)} characters; at most {NAME_LIMIT}")
    return name


def check_notes(notes: str, field: str = "notes") -> str:
    """``notes`` if they hold no control character but tabs and line breaks (``\\n``), no
    bidirectional control and no line or paragraph separator; else a one-line error naming ``field``."""
    bad = next((c for c in notes if _unsafe(c, notes=True)), None)
    if bad is not None:
        raise LidarfuzzError(f"{field}: holds the control character {bad.encode('unicode_escape').decode('ascii')}"
                             " (only tabs and line breaks are kept)")
    return notes


def add_dataset(store: Store, name: str, path: str | PathLike[str], notes: str = "",
                options: DatasetOptions | None = None) -> Dataset:
    """Open the data at ``path`` (any supported source; it is validated, never modified) with
    ``options`` and record it with them, so every later opening reads it the same way."""
    from lidarfuzz.io.open import open_dataset

    check_name(name)
    check_notes(notes)
    source = Path(path).resolve()
    options = (options or DatasetOptions()).resolved()
    dataset = open_dataset(source, options=options)
    frames = len(dataset.frame_ids())
    if frames == 0:
        raise StoreError(f"{source}: no frames to test")
    dataset[dataset.frame_ids()[0]]  # a layout that does not fit fails now, not mid-campaign
    with store.session() as s:
        if s.scalar(select(Dataset).where(Dataset.name == name)) is not None:
            raise ConflictError(f"a data set called {name!r} exists already", cli="lidarfuzz datasets list")
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

    check_name(name)
    check_notes(notes)
    system = (create_camera if modality == "camera" else create)(spec, **(options or {}))
    with store.session() as s:
        if s.scalar(select(Model).where(Model.name == name)) is not None:
            raise ConflictError(f"a model called {name!r} exists already", cli="lidarfuzz models list")
        row = Model(name=name, spec=spec, options=dict(options or {}), fingerprint=system.fingerprint(), notes=notes)
        s.add(row)
    return row


def _named(store: Store, table: type[Dataset] | type[Model], name: str, what: str, listing: str) -> Any:
    with store.session() as s:
        row = s.scalar(select(table).where(table.name == name))
        if row is None:
            raise NotFoundError(f"no {what} called {name!r}", cli=f"lidarfuzz {listing} list")
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


#: Tasks named in a refusal to forget a data set or model; the count says how many more there are
SHOWN_TASKS = 5


def _tasks_using(s: Any, table: type[_Registered], row_id: int) -> list[tuple[int, str]]:
    column = Task.dataset_id if table is Dataset else Task.model_id
    return [(task_id, task_name) for task_id, task_name in
            s.execute(select(Task.id, Task.name).where(column == row_id).order_by(Task.id))]


def tasks_using(store: Store, table: type[_Registered], name: str) -> list[tuple[int, str]]:
    """The tasks (id, name) that run on the data set or against the model ``name`` (oldest
    first): while there are any it cannot be forgotten."""
    with store.session() as s:
        row = s.scalar(select(table).where(table.name == name))
        return [] if row is None else _tasks_using(s, table, row.id)


def _used_by(kind: str, name: str, tasks: list[tuple[int, str]]) -> str:
    """``data set 'x' is used by 2 tasks (#3 noise, #5 fog); delete them first`` — the tasks named,
    so the refusal says which to delete."""
    shown = ", ".join(f"#{task_id} {task_name}".rstrip() for task_id, task_name in tasks[:SHOWN_TASKS])
    more = f" and {len(tasks) - SHOWN_TASKS} more" if len(tasks) > SHOWN_TASKS else ""
    plural, them = ("task", "it") if len(tasks) == 1 else ("tasks", "them")
    return f"{kind} {name!r} is used by {len(tasks)} {plural} ({shown}{more}); delete {them} first"


def _remove(store: Store, table: type[_Registered], name: str, kind: str) -> None:
    with store.session() as s:
        row = s.scalar(select(table).where(table.name == name))
        if row is None:
            raise NotFoundError(f"no {kind} called {name!r}")
        tasks = _tasks_using(s, table, row.id)
        if tasks:
            raise ConflictError(_used_by(kind, name, tasks))
        s.delete(row)


def remove_dataset(store: Store, name: str) -> None:
    """Forget a data set (its files are left alone)."""
    _remove(store, Dataset, name, "data set")


def remove_model(store: Store, name: str) -> None:
    """Forget a system under test (its files are left alone)."""
    _remove(store, Model, name, "model")


def _set_notes(store: Store, table: type[_Registered], name: str, notes: str, what: str, listing: str) -> Any:
    check_notes(notes)
    with store.session() as s:
        row = s.scalar(select(table).where(table.name == name))
        if row is None:
            raise NotFoundError(f"no {what} called {name!r}", cli=f"lidarfuzz {listing} list")
        row.notes = notes
        return row


def set_dataset_notes(store: Store, name: str, notes: str) -> Dataset:
    """Replace the notes of the data set ``name`` (what it is, where it came from); returns the row."""
    return _set_notes(store, Dataset, name, notes, "data set", "datasets")  # type: ignore[no-any-return]


def set_model_notes(store: Store, name: str, notes: str) -> Model:
    """Replace the notes of the system under test ``name`` (its version, training, ...); returns the row."""
    return _set_notes(store, Model, name, notes, "model", "models")  # type: ignore[no-any-return]
