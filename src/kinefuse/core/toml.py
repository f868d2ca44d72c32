"""TOML in and out: reading a TOML file a user wrote (name maps, marker maps), with errors that
name the file; :func:`dumps_toml`, the one writer of TOML documents (calibration files, rigs),
on top of ``tomli_w``; and :func:`toml_str`, a TOML string for a fragment written by hand (the
retargeting hint)."""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import tomli_w

from kinefuse.errors import InputError

#: a number as tomli_w writes it (``str`` of an int or a float: repr, ``nan``, ``inf``)
_NUMBER = r"[-+]?(?:inf|nan|[0-9][0-9._eE+-]*)"
#: an array of numbers only, one per line, as tomli_w writes every array
_NUMBER_ARRAY = re.compile(rf"\[\n((?:[ ]*{_NUMBER},\n)+)[ ]*\]")


def dumps_toml(doc: Mapping[str, Any]) -> str:
    """``doc`` as TOML text, written by ``tomli_w`` and readable by people: an array of numbers
    on one line (so a 4x4 matrix, a list of rows, is one row per line), floats as their
    ``repr`` (``tomllib`` reads back exactly the float written), strings quoted and escaped.

    Raises
    ------
    InputError
        A string holds a lone surrogate (U+D800 to U+DFFF), which no TOML (UTF-8) file can hold.
    """
    text = tomli_w.dumps(doc, indent=4)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as e:
        bad = e.object[max(0, e.start - 20) : e.end + 20]
        raise InputError(f"{bad!r} cannot be written to a TOML file (a lone surrogate)") from None
    return _NUMBER_ARRAY.sub(
        lambda m: "[" + ", ".join(v.strip().rstrip(",") for v in m[1].splitlines()) + "]", text
    )


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
    from kinefuse.core.inputs import MAX_SMALL_TEXT_BYTES, check_text_file

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
