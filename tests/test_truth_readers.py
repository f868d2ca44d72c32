"""Only the evaluation reads the simulator's truth.

A simulated session keeps its ground truth in the ``truth_*`` tables, read through
``SessionStore.truth()`` (:mod:`kinefuse.formats.store.truth`). Three rooms may touch it: the store
that holds it (``io.store``), the simulator that writes it and plays its sensors back from it
(``sim``), and the evaluation that scores against it (``evaluation``). Anything else that read it
would measure itself against the answer. ``has_truth()`` (whether a session is a simulation) is
not a read: it lets a command hand the session to the evaluation.

The check reads every module's source (AST): a call ``x.truth()``, an import of
``kinefuse.formats.store.truth`` or of its ``Truth``, or a SQL string naming a ``truth_`` table.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "kinefuse"
ALLOWED = ("kinefuse.lab", "kinefuse.sim", "kinefuse.formats.store")
_SQL = re.compile(r"\b(FROM|JOIN|INTO|UPDATE)\s+truth_\w+", re.IGNORECASE)


def _module(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def truth_reads(source: str) -> list[str]:
    """What in ``source`` reads the truth, one line each (``line: what``)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        line = getattr(node, "lineno", 0)
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "truth"
            and not node.args
        ):
            found.append(f"{line}: calls .truth()")
        elif isinstance(node, ast.ImportFrom) and node.module:
            names = {a.name for a in node.names}
            if node.module == "kinefuse.formats.store.truth" or (
                node.module == "kinefuse.formats.store" and "truth" in names
            ):
                found.append(f"{line}: imports {node.module}")
            elif "Truth" in names and node.module.startswith("kinefuse.formats.store"):
                found.append(f"{line}: imports Truth")
        elif isinstance(node, ast.Import) and any(
            a.name == "kinefuse.formats.store.truth" for a in node.names
        ):
            found.append(f"{line}: imports kinefuse.formats.store.truth")
        elif (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and _SQL.search(node.value)
        ):
            found.append(f"{line}: SQL on a truth_ table")
    return found


def test_no_truth_read_outside_evaluation_sim_and_the_store() -> None:
    bad = []
    for path in sorted(SRC.rglob("*.py")):
        mod = _module(path)
        if any(mod == a or mod.startswith(a + ".") for a in ALLOWED):
            continue
        bad += [f"{mod}:{r}" for r in truth_reads(path.read_text(encoding="utf-8"))]
    assert not bad, "truth read outside evaluation/, sim/ and io/store/:\n" + "\n".join(bad)


def test_the_allowed_rooms_do_read_it() -> None:
    """The check sees real reads: the evaluation's and the simulator's are found."""
    for rel in ("lab/fusion_truth.py", "sim/clock.py"):
        assert truth_reads((SRC / rel).read_text(encoding="utf-8")), rel


@pytest.mark.parametrize(
    "planted",
    [
        "def f(store):\n    return store.truth().motion()\n",
        "from kinefuse.formats.store.truth import Truth\n",
        "from kinefuse.formats.store import truth\n",
        "import kinefuse.formats.store.truth\n",
        'Q = "SELECT t_s FROM truth_motion ORDER BY t_s"\n',
    ],
)
def test_a_planted_read_is_caught(planted: str) -> None:
    assert truth_reads(planted)


def test_what_is_not_a_read() -> None:
    assert not truth_reads("def f(store, v):\n    return store.has_truth() and v.truth\n")
