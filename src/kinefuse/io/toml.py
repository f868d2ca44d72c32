"""Reading a TOML file a user wrote (name maps, marker maps), with errors that name the file."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from kinefuse.errors import InputError


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """The parsed TOML of ``path``; :class:`InputError` naming the file and ``what`` it should
    be (e.g. "marker map") when it cannot be read or is not valid TOML."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except OSError as e:
        raise InputError(f"{p}: cannot read the {what}: {e.strerror or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{p}: not valid TOML: {e}") from None
