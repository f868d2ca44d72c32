"""The message reference of docs/protocol.md, rendered from the message classes themselves.

``python -m kinefuse.live.protocol.wire_reference`` prints it; a test checks that docs/protocol.md
holds exactly this text between its ``<!-- messages:begin -->`` and ``<!-- messages:end -->`` marks,
so the document cannot drift from the code.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from typing import Any

from kinefuse.live.protocol.messages import MESSAGE_TYPES, Message, message_fields

BEGIN = "<!-- messages:begin -->"
END = "<!-- messages:end -->"

_ROLE_ORDER = ("sensor", "control", "server")


def _default(f: dataclasses.Field[Any]) -> str:
    if f.default is not dataclasses.MISSING:
        v = f.default
        if isinstance(v, float) and math.isnan(v):
            return "NaN"
        if v is None:
            return "nil"
        if isinstance(v, tuple):
            return "[" + ", ".join(str(x) for x in v) + "]"
        if isinstance(v, bool):
            return "false" if not v else "true"
        return f"`{v!r}`"
    if f.default_factory is not dataclasses.MISSING:
        return "empty" if f.name != "pixel_uv" else "[NaN, NaN]"
    return "required"


def message_section(cls: type[Message]) -> str:
    """Markdown for one message: heading, senders, docstring, field table."""
    senders = ", ".join(r for r in _ROLE_ORDER if r in cls.SENDERS)
    doc = inspect.cleandoc(cls.__doc__ or "").replace("``", "`")
    lines = [f"### `{cls.TYPE}` ({cls.__name__})", "", f"Sent by: {senders}.", "", doc, ""]
    lines += ["| field | wire type and limits | default |", "|---|---|---|"]
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    for name, kind in message_fields(cls):
        lines.append(f"| `{name}` | {kind.doc} | {_default(fields[name])} |")
    return "\n".join(lines) + "\n"


def render() -> str:
    """The whole generated reference (every message, in the registry's order)."""
    return "\n".join(message_section(cls) for cls in MESSAGE_TYPES.values())


def main() -> None:
    print(BEGIN)
    print(render(), end="")
    print(END)


if __name__ == "__main__":
    main()
