"""Every command's workflow returns a typed result, never a bare dict: each ``run_*`` of
``app/workflows/`` and ``pipeline/`` (and ``track_recordings``, ``fuse_multitrack``: the entries of
``kinefuse track`` and ``kinefuse realdata``) has a return annotation, and it is not
``dict``/``Mapping``."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).parents[1] / "src" / "kinefuse"
#: entry functions of commands not named run_* (kinefuse track, kinefuse realdata)
ENTRIES = {"track_recordings", "fuse_multitrack"}
DICTS = {"dict", "Dict", "Mapping", "MutableMapping"}


def bare_dict_returns(source: str, where: str) -> list[str]:
    """``where:line name -> annotation`` for each module-level entry function of ``source``
    that returns a dict (or says nothing of what it returns)."""
    bad = []
    for node in ast.parse(source).body:
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        if not (node.name.startswith("run_") or node.name in ENTRIES):
            continue
        ann = node.returns
        head = ann.value if isinstance(ann, ast.Subscript) else ann
        name = head.attr if isinstance(head, ast.Attribute) else getattr(head, "id", None)
        if isinstance(head, ast.Constant) and isinstance(head.value, str):  # a quoted annotation
            name = head.value.split("[", 1)[0].split(".")[-1]
        if ann is None or name in DICTS:
            text = "nothing" if ann is None else ast.unparse(ann)
            bad.append(f"{where}:{node.lineno} {node.name} -> {text}")
    return bad


def test_no_workflow_returns_a_bare_dict() -> None:
    files = sorted([*SRC.glob("app/workflows/*.py"), *SRC.glob("pipeline/*.py")])
    assert len(files) > 15
    bad = [b for f in files for b in bare_dict_returns(f.read_text(encoding="utf-8"), f.name)]
    assert bad == []


def test_the_check_sees_a_dict_however_it_is_written() -> None:
    planted = (
        "def run_a() -> dict[str, Any]: ...\n"
        "def run_b() -> 'Dict[str, object]': ...\n"
        "async def run_c() -> typing.Mapping[str, int]: ...\n"
        "def run_d(): ...\n"
        "def track_recordings() -> dict: ...\n"
        "def run_ok() -> FuseResult: ...\n"
        "def helper() -> dict[str, int]: ...\n"
    )
    found = [b.split()[1] for b in bare_dict_returns(planted, "x.py")]
    assert found == ["run_a", "run_b", "run_c", "run_d", "track_recordings"]
