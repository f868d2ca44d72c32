"""TOML in and out: reading a TOML file a user wrote (name maps, marker maps), with errors that
name the file, and :func:`toml_str`, the one writer of TOML strings (every TOML kinefuse writes
quotes its strings and keys through it)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from kinefuse.errors import InputError

#: TOML's short escapes; every other control character is written as a 4-digit \u escape
_ESCAPES = {
    '"': '\\"',
    "\\": "\\\\",
    "\b": "\\b",
    "\t": "\\t",
    "\n": "\\n",
    "\f": "\\f",
    "\r": "\\r",
}


def toml_str(text: str) -> str:
    """``text`` as a TOML basic string (with its quotes), for a value or a quoted key.

    Quotes, backslashes and control characters (U+0000 to U+001F and U+007F, which TOML does
    not allow raw) are escaped; every other character, non-ASCII included, is written as itself
    (the file is UTF-8). ``tomllib.loads(f"k = {toml_str(s)}")["k"] == s`` for every ``s``
    that can be written as UTF-8.

    Raises
    ------
    InputError
        ``text`` holds a lone surrogate (U+D800 to U+DFFF), which no TOML (UTF-8) file can hold.
    """
    out = ['"']
    for ch in text:
        o = ord(ch)
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif o < 0x20 or o == 0x7F:
            out.append(f"\\u{o:04X}")
        elif 0xD800 <= o <= 0xDFFF:
            raise InputError(f"{text!r} cannot be written to a TOML file (a lone surrogate)")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def toml_error(e: Exception) -> str:
    """What is wrong with a TOML text, from the error ``tomllib`` raised: its message, or, for
    the ``RecursionError`` of tables or arrays nested deeper than the parser goes, that."""
    return "tables or arrays nested too deeply" if isinstance(e, RecursionError) else str(e)


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """The parsed TOML of ``path``; :class:`InputError` naming the file and ``what`` it should
    be (e.g. "marker map") when it cannot be read or is not valid TOML."""
    from kinefuse.io.inputs import MAX_SMALL_TEXT_BYTES, check_text_file

    p = Path(path)
    try:
        check_text_file(p, what=what, max_bytes=MAX_SMALL_TEXT_BYTES)
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except OSError as e:
        raise InputError(f"{p}: cannot read the {what}: {e.strerror or e}") from None
    except (tomllib.TOMLDecodeError, RecursionError) as e:
        raise InputError(f"{p}: not valid TOML: {toml_error(e)}") from None
    except UnicodeDecodeError:
        raise InputError(f"{p}: not a text (UTF-8) file; a {what} is TOML") from None
