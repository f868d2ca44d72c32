"""docs/protocol.md holds the message reference generated from the code, and every error code."""

from __future__ import annotations

from pathlib import Path

from kinefuse.live.protocol import MESSAGE_TYPES
from kinefuse.live.protocol import wire_errors as errors
from kinefuse.live.protocol.wire_reference import BEGIN, END, render

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"


def test_the_message_reference_in_the_doc_is_the_generated_one():
    text = DOC.read_text(encoding="utf-8")
    body = text.split(BEGIN + "\n", 1)[1].split(END, 1)[0]
    assert body == render(), (
        "docs/protocol.md is stale: replace the text between its messages marks with the "
        "output of python -m kinefuse.live.protocol.wire_reference"
    )
    for cls in MESSAGE_TYPES.values():
        assert f"### `{cls.TYPE}` ({cls.__name__})" in text


def test_every_error_code_is_documented_and_every_exception_has_one():
    text = DOC.read_text(encoding="utf-8")
    table = text.split("<!-- codes:begin -->", 1)[1].split("<!-- codes:end -->", 1)[0]
    for code, meaning in errors.ERROR_CODES.items():
        assert f"| `{code}` | {meaning} |" in table

    def subclasses(c: type) -> list[type]:
        return [c, *(x for s in c.__subclasses__() for x in subclasses(s))]

    for cls in subclasses(errors.WireError):
        if cls not in (errors.WireError, errors.RemoteError):
            assert cls.code in errors.ERROR_CODES, cls
