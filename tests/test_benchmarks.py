"""Every benchmark and every study has a ``--smoke`` mode, and CI runs them all (none rots).

``benchmarks/`` holds the speed, memory, load and soak harnesses; ``studies/`` the fits, sweeps,
comparisons and probes behind the documented figures (the scripts that read ``../shared/data``).
``.ci/run`` runs ``python FOLDER/X.py --smoke`` for every ``benchmarks/*.py`` and
``studies/*.py``, one loop, so a new one cannot be forgotten; running them is CI's job. Here,
without running anything: each file declares the option (``add_argument("--smoke", ...)``, read
from its syntax tree) and imports neither pytest nor a test module (it runs without the test
extra).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = sorted((ROOT / "benchmarks").glob("*.py")) + sorted((ROOT / "studies").glob("*.py"))

#: a study that reads ``analysis_accuracy.py accuracy --save`` folders declares ``--smoke``
#: through that script's shared arguments
SHARED_SMOKE = "saved_takes_arguments"


def _declares_smoke(tree: ast.AST) -> bool:
    shared = any(
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == SHARED_SMOKE
        for node in ast.walk(tree)
    )
    return shared or any(
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


def test_there_are_benchmarks_and_studies() -> None:
    assert len([p for p in BENCHMARKS if p.parent.name == "benchmarks"]) >= 10
    assert len([p for p in BENCHMARKS if p.parent.name == "studies"]) >= 10


def test_nothing_installed_reads_the_shared_data() -> None:
    """``../shared`` is this repository's data, not an installed user's: only tests, benchmarks
    and studies may name it in code (a provenance note in a docstring or comment is fine)."""
    offenders = []
    for path in sorted((ROOT / "src" / "kinefuse").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and node.value == "shared":
                offenders.append(str(path.relative_to(ROOT)))
    assert not offenders, f"installed code builds a path to ../shared: {offenders}"


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
    assert "benchmarks/*.py studies/*.py" in ci and "--smoke" in ci
    # after the tests, before the linters, which read both folders
    assert ci.index("-m pytest") < ci.index("benchmarks/*.py") < ci.index("ruff check")
    assert "ruff check src tests benchmarks studies" in ci
