"""Safe input files: a user's text file is looked at before it is read whole.

A file named on the command line may be anything: a 2 GB sparse file under a ``.trc`` name, a
binary, a gzip bomb. :func:`read_text` checks, in this order and before reading more than
:data:`HEAD_BYTES`:

1. **Size.** A file over the limit of its kind (:data:`MAX_TEXT_BYTES` for motion and marker
   files, :data:`MAX_SMALL_TEXT_BYTES` for TOML) is refused by its size alone; a ``.gz`` file is
   decompressed no further than the limit.
2. **First bytes.** Text formats never hold a NUL byte: a file whose first bytes do, is a binary
   (or a sparse file's hole), not the text it is named as.
3. **First line.** The caller's check of the first line (``PathFileType`` for TRC, ...).

Each failure is one :class:`~kinefuse.errors.InputError` (or the caller's kind of it) naming the
file, what it should have been and what was found. Inputs are opened read-only.
"""

from __future__ import annotations

import gzip
import os
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Final

from kinefuse.errors import InputError

__all__ = [
    "HEAD_BYTES",
    "LINE_LIMIT",
    "MAX_SMALL_TEXT_BYTES",
    "MAX_TEXT_BYTES",
    "check_text_file",
    "read_text",
]

#: The largest motion or marker text file read (BVH, ASF/AMC, TRC, .mot, CSV logs): 256 MiB is
#: about 40 minutes of 40 markers at 100 Hz in TRC; reading it takes a few GB of memory.
MAX_TEXT_BYTES: Final = 256 * 2**20
#: The largest TOML file read (rigs, calibrations, name and marker maps: a few kB each).
MAX_SMALL_TEXT_BYTES: Final = 16 * 2**20
#: Bytes read to check a file's first bytes and first line before it is read whole.
HEAD_BYTES: Final = 64 * 2**10
#: The longest line a recognizer of kinefuse's own outputs reads (``readline(LINE_LIMIT)``): a
#: file of one 2 GB line is not read whole to learn that kinefuse did not write it.
LINE_LIMIT: Final = 1 << 16

#: ``fail(message, line) -> error``: the error to raise (a reader's own kind of InputError).
Fail = Callable[[str, int | None], InputError]
#: ``check(first_line) -> None or what is wrong with it``.
FirstLineCheck = Callable[[str], str | None]


def _size_text(n: int) -> str:
    if n >= 2**30:
        return f"{n / 2**30:.4g} GiB"
    return f"{n / 2**20:.4g} MiB" if n >= 2**20 else f"{n / 2**10:.4g} KiB"


def _default_fail(path: Path) -> Fail:
    def fail(message: str, line: int | None) -> InputError:
        where = f"{path}:{line}" if line is not None else str(path)
        return InputError(f"{where}: {message}")

    return fail


def read_text(
    path: str | os.PathLike[str],
    *,
    what: str,
    first_line: FirstLineCheck | None = None,
    max_bytes: int = MAX_TEXT_BYTES,
    fail: Fail | None = None,
) -> str:
    """The text of a user's file (UTF-8, undecodable bytes replaced), checked before it is read
    whole; a ``.gz`` file is decompressed on the fly.

    Parameters
    ----------
    path : path-like
        The file, opened read-only.
    what : str
        What the file should be ("TRC marker file", "BVH file", ...), for messages.
    first_line : callable, optional
        ``first_line(line) -> None`` when the first line (of the first :data:`HEAD_BYTES`) is
        right, else what is wrong with it.
    max_bytes : int
        The largest file read (decompressed size for ``.gz``).
    fail : callable, optional
        ``fail(message, line) -> InputError`` builds the error (default: an
        :class:`InputError` starting with ``path:line:``).

    Raises
    ------
    InputError
        (or what ``fail`` builds) The file cannot be read, is larger than ``max_bytes``, holds
        NUL bytes in its first :data:`HEAD_BYTES`, or its first line fails ``first_line``.
    """
    p = Path(path)
    fail = fail or _default_fail(p)
    gz = p.suffix.lower() == ".gz"
    try:
        if not gz:
            _check_size(p, what, max_bytes, fail)
        with gzip.open(p, "rb") if gz else p.open("rb") as f:
            head = f.read(HEAD_BYTES)
            _check_head(head, what, first_line, fail)
            data = head + f.read(max(0, max_bytes + 1 - len(head)))
            if len(data) > max_bytes:  # a .gz that expands past the limit (a gzip bomb)
                raise fail(
                    f"the file expands to more than the {_size_text(max_bytes)} kinefuse reads "
                    f"from a {what}; check that this is the file you meant",
                    None,
                )
    except (OSError, EOFError, zlib.error) as e:
        why = e.strerror if isinstance(e, OSError) and e.strerror else str(e) or type(e).__name__
        raise fail(f"cannot read the file: {why}", None) from None
    return data.decode("utf-8", errors="replace")


def check_text_file(
    path: str | os.PathLike[str],
    *,
    what: str,
    first_line: FirstLineCheck | None = None,
    max_bytes: int = MAX_TEXT_BYTES,
    fail: Fail | None = None,
) -> None:
    """:func:`read_text`'s checks alone (size, first bytes, first line; no more than
    :data:`HEAD_BYTES` read), for a reader that reads the file its own way afterwards. An
    ``OSError`` (a missing file, ...) is the caller's to report."""
    p = Path(path)
    fail = fail or _default_fail(p)
    _check_size(p, what, max_bytes, fail)
    with p.open("rb") as f:
        head = f.read(HEAD_BYTES)
    _check_head(head, what, first_line, fail)


def _check_size(p: Path, what: str, max_bytes: int, fail: Fail) -> None:
    size = p.stat().st_size
    if size > max_bytes:
        raise fail(
            f"the file is {_size_text(size)}, more than the {_size_text(max_bytes)} kinefuse "
            f"reads from a {what}; check that this is the file you meant (a longer take: cut "
            "it into parts)",
            None,
        )


def _check_head(head: bytes, what: str, first_line: FirstLineCheck | None, fail: Fail) -> None:
    """The checks of a file's first :data:`HEAD_BYTES` (see the module docstring)."""
    if b"\x00" in head:
        at = head.index(b"\x00")
        line = head.count(b"\n", 0, at) + 1
        raise fail(
            f"not a text file (byte {at + 1} is a NUL byte): a binary or damaged file, not a "
            f"{what}",
            line,
        )
    if first_line is None:
        return
    end = head.find(b"\n")
    if end < 0 and len(head) == HEAD_BYTES:
        raise fail(
            f"the first line is longer than {HEAD_BYTES // 1024} KiB: not a {what}",
            1,
        )
    text = head[: end if end >= 0 else len(head)].decode("utf-8", errors="replace")
    problem = first_line(text.lstrip("\ufeff").rstrip("\r"))
    if problem is not None:
        raise fail(problem, 1)
