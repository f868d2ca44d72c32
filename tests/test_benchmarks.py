"""Every benchmark has a ``--smoke`` mode, and CI runs them all (issue 23: benchmarks never rot).

``.ci/run`` runs ``python benchmarks/X.py --smoke`` for every ``benchmarks/*.py``, one loop, so
a new benchmark cannot be forgotten; running them is CI's job. Here, without running anything:
each file declares the option (``add_argument("--smoke", ...)``, read from its syntax tree) and
imports neither pytest nor a test module (a benchmark must run without the test extra).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = sorted((ROOT / "benchmarks").glob("*.py"))


def _declares_smoke(tree: ast.AST) -> bool:
    return any(
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == "add_argument"
        and any(isinstance(a, ast.Constant) and a.value == "--smoke" for a in node.args)
        for node in ast.walk(tree)
    )


def _imported(tree: ast.AST) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module.split(".")[0])
    return names


def test_there_are_benchmarks() -> None:
    assert len(BENCHMARKS) >= 10


@pytest.mark.parametrize("path", BENCHMARKS, ids=lambda p: p.name)
def test_benchmark_has_a_smoke_mode(path: Path) -> None:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    assert _declares_smoke(tree), f"{path.name} has no --smoke option (CI runs every benchmark so)"
    assert "--smoke" in (ast.get_docstring(tree) or ""), f"{path.name}'s docstring omits --smoke"


@pytest.mark.parametrize("path", BENCHMARKS, ids=lambda p: p.name)
def test_benchmark_imports_no_test_code(path: Path) -> None:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    bad = {
        n for n in _imported(tree) if n in {"pytest", "conftest", "tests"} or n.startswith("test_")
    }
    assert not bad, f"{path.name} imports {sorted(bad)}: a benchmark runs without the test extra"


def test_ci_runs_every_benchmark_smoke_mode() -> None:
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert "benchmarks/*.py" in ci and "--smoke" in ci
    # after the tests, before the linters
    assert ci.index("-m pytest") < ci.index("benchmarks/*.py") < ci.index("ruff check")
