"""Safe output files and folders: every command writes through here.

Three rules hold for everything kinefuse writes:

1. **Never overwrite a file kinefuse did not make.** An existing output is replaced only when a
   recognizer for its kind says kinefuse wrote it (a session by its SQLite schema, an export by
   its header, a calibration by its ``format`` key, an output folder by its marker file); any
   other file is refused with a message that names it.
2. **Atomic replace.** The new content is written to a temporary file in the same folder and
   renamed over the target only once it is complete (``os.replace``), so an interrupted or
   failed run leaves the old file intact. Folders are built beside the target and swapped in.
3. **Fail loudly.** A write that fails, or that leaves no file behind, raises
   :class:`~kinefuse.errors.OutputError` naming the path and the reason.

What kinefuse writes holds captured motion (sessions, exports, analyses and their figures), so
it is private to the user: files are made with mode 0600 and folders 0700, whatever the umask
(``chmod`` one to share it).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sqlite3
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from kinefuse.errors import OutputError

__all__ = [
    "DIR_MARKER",
    "atomic_dir",
    "atomic_file",
    "atomic_write_text",
    "check_output_folder",
    "is_kinefuse_session",
    "never_replace",
    "refuse_unless_ours",
]

#: Name of the marker file kinefuse leaves in every output folder it makes.
DIR_MARKER = ".kinefuse-output"

Recognizer = Callable[[Path], bool]


def check_output_folder(path: Path, what: str = "output") -> None:
    """Raise :class:`OutputError` unless ``path``'s folder exists and can be written."""
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.exists():
        raise OutputError(
            f"cannot write {what} {path}: folder {folder} does not exist; create it first or "
            "choose another path"
        )
    if not folder.is_dir():
        raise OutputError(f"cannot write {what} {path}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(
            f"cannot write {what} {path}: folder {folder} is not writable (read-only media or "
            "no permission); choose another path"
        )


#: ``PRAGMA application_id`` of a kinefuse session store ("KNFS"), so ``file(1)`` can tell (here,
#: below the store, because every writer asks whether a file is a session before replacing it).
APPLICATION_ID = 0x4B4E4653

#: Extensions of other formats that a session store (SQLite) must not be written under.
FOREIGN_SESSION_SUFFIXES = frozenset(
    {".c3d", ".trc", ".csv", ".toml", ".json", ".bvh", ".amc", ".asf", ".mot", ".png", ".txt",
     ".md", ".npy", ".npz", ".mkv", ".gz", ".html", ".xml", ".osim", ".py"}
)  # fmt: skip


def is_kinefuse_session(path: Path) -> bool:
    """True if ``path`` is a SQLite file with kinefuse's session schema (not by its extension)."""
    try:
        with path.open("rb") as f:
            if f.read(16) != b"SQLite format 3\x00":
                return False
        conn = sqlite3.connect(path.resolve().as_uri() + "?mode=ro", uri=True)
        try:
            app_id = conn.execute("PRAGMA application_id").fetchone()[0]
            has_meta = conn.execute(
                "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'meta'"
            ).fetchone()
            return bool(app_id == APPLICATION_ID and has_meta)
        finally:
            conn.close()
    except (OSError, sqlite3.Error):
        return False


def is_png(path: Path) -> bool:
    """The recognizer of a figure that a command may redraw: any existing PNG file (a file of
    another kind at its path is refused)."""
    try:
        with Path(path).open("rb") as f:
            return f.read(8) == b"\x89PNG\r\n\x1a\n"
    except OSError:
        return False


def never_replace(_path: Path) -> bool:
    """The recognizer of a file kinefuse only ever writes new (a table or a plot written into a
    folder the caller names): any existing file at its path is refused."""
    return False


def _is_kinefuse_dir(path: Path) -> bool:
    return (path / DIR_MARKER).is_file()


def refuse_unless_ours(path: Path, recognizer: Recognizer, what: str) -> None:
    """Raise :class:`OutputError` if ``path`` exists and ``recognizer`` does not claim it."""
    if path.is_dir() and not path.is_symlink():
        raise OutputError(f"cannot write {what} {path}: it is a folder")
    if path.exists() and not recognizer(path):
        raise OutputError(
            f"refusing to replace {path}: it exists and was not written by kinefuse as a {what}; "
            "move it away or choose another path"
        )


#: The mode of every file kinefuse writes (and of a session store it creates): the user's only.
PRIVATE_FILE_MODE = 0o600


def _temp_beside(path: Path, suffix: str = ".partial") -> Path:
    """A new empty file beside ``path`` with mode :data:`PRIVATE_FILE_MODE` (as ``mkstemp``
    makes it; the renamed output keeps it)."""
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent or ".")
    os.close(fd)
    return Path(name)


def _fsync(path: Path) -> None:
    with contextlib.suppress(OSError), path.open("rb") as f:
        os.fsync(f.fileno())


@contextlib.contextmanager
def atomic_file(
    path: str | os.PathLike[str],
    *,
    what: str,
    recognizer: Recognizer,
    suffix: str = ".partial",
) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it over ``path``.

    Parameters
    ----------
    path : path-like
        The final file. Its folder must exist and be writable.
    what : str
        What the file is, for messages ("TRC export", "calibration file", ...).
    recognizer : callable
        ``recognizer(existing_path) -> bool``: True when an existing file at ``path`` was made
        by kinefuse as this kind of output and may be replaced.

    Raises
    ------
    OutputError
        The target is someone else's file, its folder is missing or read-only, the writer
        raised an ``OSError``, or it left no (or an empty) file behind. The temporary file is
        removed and any old file at ``path`` is left untouched.
    """
    target = Path(path)
    check_output_folder(target, what)
    refuse_unless_ours(target, recognizer, what)
    try:
        tmp = _temp_beside(target, suffix)
    except OSError as e:
        raise OutputError(f"cannot write {what} {target}: {e.strerror or e}") from None
    try:
        yield tmp
        if not tmp.exists() or tmp.stat().st_size == 0:
            raise OutputError(f"writing {what} {target} failed: the writer produced no data")
        _fsync(tmp)
        # a concurrent process may have put a foreign file there meanwhile: check again
        refuse_unless_ours(target, recognizer, what)
        os.replace(tmp, target)
    except OSError as e:
        raise OutputError(f"writing {what} {target} failed: {e.strerror or e}") from None
    finally:
        # the temporary file, and the journal companions SQLite may have left beside it
        for leftover in (tmp, *(tmp.with_name(tmp.name + s) for s in ("-wal", "-shm", "-journal"))):
            with contextlib.suppress(OSError):
                leftover.unlink()


def atomic_write_text(
    path: str | os.PathLike[str], text: str, *, what: str, recognizer: Recognizer
) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through :func:`atomic_file`; return the path."""
    with atomic_file(path, what=what, recognizer=recognizer) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def atomic_write_lines(
    path: str | os.PathLike[str], lines: Iterable[str], *, what: str, recognizer: Recognizer
) -> Path:
    """:func:`atomic_write_text` of the lines' concatenation, written as they come (a long
    table is never one string in memory); the same bytes."""
    with (
        atomic_file(path, what=what, recognizer=recognizer) as tmp,
        open(tmp, "w", encoding="utf-8") as f,
    ):
        f.writelines(lines)
    return Path(path)


#: The largest JSON file :func:`json_recognizer` reads to see whether kinefuse wrote it.
RECOGNIZED_JSON_BYTES = 64 * 2**20


def json_recognizer(key: str, value: object) -> Recognizer:
    """A recognizer for JSON files kinefuse writes: a top-level object with ``key == value``."""

    def recognize(p: Path) -> bool:
        try:
            if p.stat().st_size > RECOGNIZED_JSON_BYTES:
                return False  # not read whole: a large file is no JSON kinefuse wrote
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError):
            return False
        return isinstance(d, dict) and d.get(key) == value

    return recognize


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike[str], *, what: str) -> Iterator[Path]:
    """Yield a fresh temporary folder beside ``path``; on success swap it in as ``path``.

    An existing ``path`` is replaced only when it is empty or an output folder kinefuse made
    (it holds :data:`DIR_MARKER`); the old folder stays in place until the new one is complete.
    On failure the temporary folder is removed and ``path`` is left as it was.
    """
    target = Path(path)
    check_output_folder(target, what)
    if target.exists():
        if not target.is_dir():
            raise OutputError(f"cannot write {what} {target}: it exists and is not a folder")
        if any(target.iterdir()) and not _is_kinefuse_dir(target):
            raise OutputError(
                f"refusing to write {what} into {target}: the folder holds files kinefuse did not "
                "write; choose an empty or new folder"
            )
    parent = target.parent
    try:
        # mkdtemp makes it 0700: private, as the files in it
        tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=parent))
    except OSError as e:
        raise OutputError(f"cannot write {what} {target}: {e.strerror or e}") from None
    old: Path | None = None
    try:
        (tmp / DIR_MARKER).write_text(f"written by kinefuse: {what}\n", encoding="utf-8")
        yield tmp
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=parent))
            os.replace(target, old / target.name)
        os.replace(tmp, target)
    except OSError as e:
        if old is not None and not target.exists():
            with contextlib.suppress(OSError):
                os.replace(old / target.name, target)  # put the old folder back
        raise OutputError(f"writing {what} {target} failed: {e.strerror or e}") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
