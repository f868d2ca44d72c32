"""Safe file writes: a temporary file in the target's folder, then an atomic rename.

A reader never sees a half-written file, a crash leaves at most a hidden ``.NAME.*.tmp`` file,
and an existing file is never replaced unless the caller says it made it (``overwrite=True``).
Without ``overwrite`` the final step is a hard link (``os.link``), which fails atomically when
the name exists; on file systems without hard links it falls back to a check and
``os.replace``.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from kinefuse.errors import KinefuseError

__all__ = ["WriteError", "atomic_write", "atomic_write_text", "temp_path"]


class WriteError(KinefuseError):
    """An output file could not be written (permissions, full disk, name taken)."""


def _umask() -> int:
    """The process's file-creation mask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _fail(path: Path, e: OSError, what: str = "cannot write") -> WriteError:
    why = e.strerror or str(e)
    return WriteError(f"{path}: {what}: {why}; choose another output folder or fix its rights")


@contextlib.contextmanager
def temp_path(path: str | Path, *, overwrite: bool = False) -> Iterator[Path]:
    """A temporary path beside ``path`` to write into; renamed onto ``path`` on success.

    Parameters
    ----------
    path : str or Path
        The final file.
    overwrite : bool
        Replace ``path`` if it exists (only for files the caller made).

    Raises
    ------
    WriteError
        The folder is not writable, the name is taken (without ``overwrite``), the write failed.
    """
    p = Path(path)
    if not overwrite and p.exists():
        raise WriteError(f"{p} already exists; kinefuse does not overwrite files it did not make")
    try:
        fd, tmp_name = tempfile.mkstemp(
            prefix=f".{p.name}.", suffix=".tmp" + p.suffix, dir=p.parent
        )
    except OSError as e:
        raise _fail(p, e) from None
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a finished file gets the usual mode
    try:
        yield tmp
        if overwrite:
            os.replace(tmp, p)
        else:
            try:
                os.link(tmp, p)
            except FileExistsError:
                raise WriteError(
                    f"{p} appeared while it was being written; it was left alone"
                ) from None
            except OSError:
                if p.exists():
                    raise WriteError(f"{p} already exists; it was left alone") from None
                os.replace(tmp, p)
    except OSError as e:
        raise _fail(p, e) from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def atomic_write(
    path: str | Path, write: Callable[[Path], None], *, overwrite: bool = False
) -> Path:
    """Call ``write(tmp_path)`` and move the result onto ``path`` (see :func:`temp_path`)."""
    with temp_path(path, overwrite=overwrite) as tmp:
        write(tmp)
    return Path(path)


def atomic_write_text(path: str | Path, text: str, *, overwrite: bool = False) -> Path:
    """Write ``text`` (UTF-8, ``\\n`` line ends) to ``path`` through a temporary file."""

    def write(tmp: Path) -> None:
        with tmp.open("w", encoding="utf-8", newline="\n") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())

    return atomic_write(path, write, overwrite=overwrite)
