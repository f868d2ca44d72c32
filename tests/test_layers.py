"""No arrow up: every import in the package points to its own room or a lower one.

The table is the one in ``docs/architecture.md`` (:func:`test_the_docs_hold_the_same_table`
keeps the two together). A room is a top-level folder (or module) of ``src/kinefuse``; a row of
the table holds one or more rooms, a later one of a row may import an earlier one. An import at
module level or inside a function, ``import x`` or ``from x import y``, counts the same.
"""

from __future__ import annotations

import ast
import pickle
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "src" / "kinefuse"

#: The layer table from the bottom up: each row's rooms, in their order within the row.
TABLE: tuple[tuple[str, ...], ...] = (
    ("errors", "core"),
    ("capture",),
    ("biomech",),
    ("formats",),
    ("sim", "devices"),
    ("pipeline",),
    ("lab",),
    ("live",),
    ("app", "api", "__main__"),
)

#: Rooms from the bottom up ("": the package's own ``__init__``, the version and a lazy facade).
LAYERS: tuple[str, ...] = ("", *(room for row in TABLE for room in row))

#: Imports the order alone would allow but the design forbids: (importer, imported), each a
#: dotted prefix below ``kinefuse``.
FORBIDDEN: tuple[tuple[str, str], ...] = (
    ("lab.report", "formats.store"),  # rendering only: takes results, reads no store
    ("lab.report", "pipeline"),
    ("live.viewer", "live.server"),  # the viewer knows the server only through live/bus.py
    ("live.viewer", "live.client"),
    ("live.server", "live.client"),  # the two ends of the wire share only the protocol
    ("live.client", "live.server"),
    ("live.server", "live.viewer"),  # the viewer is handed to the server as a service
    ("live.lsl", "live.server"),  # a service knows the server only through live/bus.py
    ("live.lsl", "live.client"),
    ("live.protocol", "live"),  # sans-I/O: the protocol imports nothing else of live
)


def _within(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def room_of(module: str) -> str | None:
    """The room of ``kinefuse.a.b.c``: ``a`` when it is in :data:`LAYERS`."""
    parts = module.split(".")[1:]
    if not parts:
        return ""
    return parts[0] if parts[0] in LAYERS else None


def _module_name(path: Path, root: Path) -> str:
    rel = path.relative_to(root.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _parse(path: Path) -> ast.Module:
    """The file's syntax tree. CPython 3.11's AST constructor keeps a process-wide recursion
    count that an earlier error elsewhere in the process can leave off (gh-106905: "AST
    constructor recursion depth mismatch", seen in the full suite); then a fresh interpreter
    parses it."""
    try:
        return ast.parse(path.read_text(), filename=str(path))
    except SystemError:
        code = "import ast, pickle, sys; p = sys.argv[1]; "
        code += "sys.stdout.buffer.write(pickle.dumps(ast.parse(open(p).read(), p)))"
        out = subprocess.run(
            [sys.executable, "-c", code, str(path)], capture_output=True, check=True
        ).stdout
        tree = pickle.loads(out)
        assert isinstance(tree, ast.Module)
        return tree


def _imports(path: Path, module: str) -> list[tuple[int, str]]:
    """Every ``kinefuse...`` module (or ``kinefuse.x.name``) imported by the file, with its line."""
    tree = _parse(path)
    is_pkg = path.name == "__init__.py"
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.startswith("kinefuse")]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_pkg else module.split(".")[:-1]
                base = base[: len(base) - node.level + 1]
                target = ".".join([*base, *([node.module] if node.module else [])])
            else:
                target = node.module or ""
            if target.split(".")[0] == "kinefuse":
                out += [(node.lineno, f"{target}.{a.name}") for a in node.names]
    return out


def _forbidden(module: str, target: str) -> bool:
    """Whether ``module`` importing ``target`` breaks a rule of :data:`FORBIDDEN` (a rule's
    importer may still import itself)."""
    here, there = module.partition(".")[2], target.partition(".")[2]
    return any(
        _within(here, a) and _within(there, b) and not _within(there, a) for a, b in FORBIDDEN
    )


def layer_violations(root: Path) -> list[str]:
    """Each import of the package at ``root`` that points up the table or is forbidden."""
    order = {room: i for i, room in enumerate(LAYERS)}
    found = []
    for path in sorted(root.rglob("*.py")):
        module = _module_name(path, root)
        here = room_of(module)
        lazy_facade = path == root / "__init__.py"
        if here is None:
            found.append(f"{path}: module {module} is in no room of the layer table")
            continue
        for line, target in _imports(path, module):
            there = room_of(target)
            if there is None or (lazy_facade and there == "api"):
                continue
            where = f"{path.relative_to(root.parent)}:{line} ({here} -> {there}: {target})"
            if order[there] > order[here]:
                found.append(f"upward import {where}")
            elif _forbidden(module, target):
                found.append(f"forbidden import {where}")
    return found


def test_no_import_points_up() -> None:
    violations = layer_violations(PACKAGE)
    assert not violations, "\n".join(violations)


def test_at_most_ten_rooms_and_rows() -> None:
    packages = sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists())
    assert len(packages) <= 10, packages
    assert set(packages) <= set(LAYERS), f"not in the layer table: {set(packages) - set(LAYERS)}"
    assert len(TABLE) <= 10


def test_the_docs_hold_the_same_table() -> None:
    text = (REPO / "docs" / "architecture.md").read_text()
    section = text.split("\n## The layers\n", 1)[1].split("\n## ", 1)[0]
    rows = [
        tuple(re.findall(r"`([\w.]+)`", line.split("|")[1]))
        for line in section.splitlines()
        if line.startswith("| `")
    ]
    assert tuple(rows) == TABLE


def test_package_root_holds_only_folders() -> None:
    loose = sorted(
        p.name
        for p in PACKAGE.iterdir()
        if p.is_file()
        and p.name not in {"__init__.py", "__main__.py", "errors.py", "api.py", "py.typed"}
    )
    assert loose == []


def test_every_folder_says_what_it_may_import() -> None:
    for init in sorted(PACKAGE.rglob("__init__.py")):
        doc = ast.get_docstring(_parse(init))
        assert doc and len(doc) > 80, f"{init}: no docstring saying what lives there"
    for row in TABLE:
        for room in row:
            init = PACKAGE / room / "__init__.py"
            if init.exists():
                doc = ast.get_docstring(_parse(init)) or ""
                assert "import" in doc, f"{init}: the docstring says not what it may import"


def test_no_two_modules_share_a_mistakable_name() -> None:
    """A module name used twice (``session.py`` of the store and of the fusion) reads as one
    thing. The command pairs of ``app`` (``cli/x.py`` parses, ``workflows/x.py`` runs) are one
    command and do not count."""
    seen: dict[str, list[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).as_posix()
        if path.name not in {"__init__.py", "__main__.py"} and not rel.startswith("app/"):
            seen.setdefault(path.stem, []).append(rel)
    for name in ("session", "guard", "clock", "codec", "depth", "server", "sources", "view"):
        assert len(seen.get(name, [])) <= 1, (name, seen[name])


def _write(root: Path, rel: str, text: str) -> None:
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


@pytest.mark.parametrize(
    ("source", "expect"),
    [
        ("from kinefuse.app.cli import main\n", "upward import"),  # module level
        ("def f():\n    import kinefuse.live.server.server\n", "upward import"),  # in a function
        ("from kinefuse import app\n", "upward import"),  # a room imported as a name
        ("from .. import lab\n", "upward import"),  # relative
        ("from kinefuse.core.geometry import transforms\n", None),  # down: fine
    ],
)
def test_the_check_catches_an_upward_import(
    tmp_path: Path, source: str, expect: str | None
) -> None:
    root = tmp_path / "kinefuse"
    _write(root, "__init__.py", "")
    _write(root, "capture/__init__.py", "")
    _write(root, "capture/bad.py", source)
    found = layer_violations(root)
    if expect is None:
        assert found == []
    else:
        assert len(found) == 1 and found[0].startswith(expect), found
        assert "capture/bad.py" in found[0]


@pytest.mark.parametrize(
    ("importer", "source"),
    [
        ("live/viewer/planted.py", "from kinefuse.live.server import server\n"),
        ("live/server/planted.py", "from kinefuse.live.client.client import SensorClient\n"),
        ("live/lsl.py", "import kinefuse.live.client\n"),
        ("live/protocol/planted.py", "from kinefuse.live import bus\n"),
        ("lab/report/planted.py", "from kinefuse.formats.store import truth\n"),
    ],
)
def test_the_check_catches_a_forbidden_import(tmp_path: Path, importer: str, source: str) -> None:
    root = tmp_path / "kinefuse"
    _write(root, "__init__.py", "")
    _write(root, importer, source)
    found = layer_violations(root)
    assert len(found) == 1 and found[0].startswith("forbidden import"), found


def _copy_of_the_package(tmp_path: Path) -> Path:
    root = tmp_path / "kinefuse"
    shutil.copytree(PACKAGE, root, ignore=shutil.ignore_patterns("__pycache__", "data", "static"))
    assert layer_violations(root) == []
    return root


def test_an_upward_import_planted_in_the_package_fails_the_check(tmp_path: Path) -> None:
    """The real package, copied; one line of the analysis path made to reach up into a reader."""
    root = _copy_of_the_package(tmp_path)
    target = root / "biomech" / "marker_maps.py"
    target.write_text(target.read_text() + "\nfrom kinefuse.formats.markers import read_trc\n")
    found = layer_violations(root)
    assert len(found) == 1 and found[0].startswith("upward import"), found
    assert "biomech -> formats" in found[0]


def test_a_module_outside_every_room_fails_the_check(tmp_path: Path) -> None:
    root = _copy_of_the_package(tmp_path)
    _write(root, "gadgets/__init__.py", '"""A room the table does not know."""\n')
    found = layer_violations(root)
    assert len(found) == 1 and "in no room of the layer table" in found[0], found
