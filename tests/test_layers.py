"""No arrow up: every import in the package points to its own room or a lower one.

The table is the one in ``docs/architecture.md`` (keep the two together). A room is a folder (or
a module) of ``src/kinefuse``; a module belongs to the room of its longest matching prefix. An
import at module level or inside a function, ``import x`` or ``from x import y``, counts the same.
"""

from __future__ import annotations

import ast
import pickle
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "kinefuse"

#: Rooms from the bottom up. A module may import its own room and any room listed before it.
LAYERS: tuple[str, ...] = (
    "",  # the package itself (kinefuse/__init__.py: the version, nothing imported)
    "errors",
    "io",  # io/ itself: safe writes, checked reads, TOML (outputs.py, inputs.py, toml.py)
    "skeleton",
    "geometry",
    "camera",
    "frames",
    "protocol",
    "motion",
    "sync",
    "occlusion",
    "calibration",
    "fusion",
    "analysis",
    "io.store",
    "sim",
    "io.formats",
    "devices",  # real cameras (sources) and body trackers: entry-point plug-ins
    "pipeline",
    "evaluation",
    "report",
    "net",  # net/__init__.py only: a docstring
    "net.bus",
    "net.proxy",
    "net.client",
    "net.server",
    "net.lsl",  # the LSL outlet: a service on the publisher, handed to the server by workflows
    "viewer",
    "workflows",
    "api",  # the Python API (the package's __getattr__ re-exports it, loaded on first use)
    "cli",
    "__main__",
)

#: Imports the order alone would allow but the design forbids: (importer room, imported room).
FORBIDDEN: tuple[tuple[str, str], ...] = (
    ("report", "io.store"),  # rendering only: takes results, reads no store
    ("report", "pipeline"),
    ("viewer", "net.server"),  # the viewer knows the server only through net/bus.py
    ("viewer", "net.client"),
    ("net.server", "net.client"),  # the two ends of the wire share only protocol/
    ("net.client", "net.server"),
    ("net.lsl", "net.server"),  # a service knows the server only through net/bus.py
    ("net.lsl", "net.client"),
)


def room_of(module: str) -> str | None:
    """The room of ``kinefuse.a.b.c`` (longest prefix of ``a.b.c`` in :data:`LAYERS`)."""
    parts = module.split(".")[1:]
    if not parts:
        return ""
    for n in range(len(parts), 0, -1):
        key = ".".join(parts[:n])
        if key in LAYERS:
            return key
    return None


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
            if there is None or there == here or (lazy_facade and there == "api"):
                continue
            where = f"{path.relative_to(root.parent)}:{line} ({here} -> {there}: {target})"
            if order[there] > order[here]:
                found.append(f"upward import {where}")
            elif (here, there) in FORBIDDEN or any(
                here == a and (there == b or there.startswith(b + ".")) for a, b in FORBIDDEN
            ):
                found.append(f"forbidden import {where}")
    return found


def test_no_import_points_up() -> None:
    violations = layer_violations(PACKAGE)
    assert not violations, "\n".join(violations)


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


def _write(root: Path, rel: str, text: str) -> None:
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


@pytest.mark.parametrize(
    ("source", "expect"),
    [
        ("from kinefuse.cli import main\n", "upward import"),  # module level
        ("def f():\n    import kinefuse.net.server.server\n", "upward import"),  # in a function
        ("from kinefuse import workflows\n", "upward import"),  # a room imported as a name
        ("from .. import report\n", "upward import"),  # relative
        ("from kinefuse.geometry import transforms\n", None),  # down: fine
    ],
)
def test_the_check_catches_an_upward_import(
    tmp_path: Path, source: str, expect: str | None
) -> None:
    root = tmp_path / "kinefuse"
    _write(root, "__init__.py", "")
    _write(root, "fusion/__init__.py", "")
    _write(root, "fusion/bad.py", source)
    found = layer_violations(root)
    if expect is None:
        assert found == []
    else:
        assert len(found) == 1 and found[0].startswith(expect), found
        assert "fusion/bad.py" in found[0]


def test_the_check_catches_a_forbidden_import(tmp_path: Path) -> None:
    root = tmp_path / "kinefuse"
    _write(root, "__init__.py", "")
    _write(root, "viewer/__init__.py", "from kinefuse.net.server.server import Server\n")
    found = layer_violations(root)
    assert len(found) == 1 and found[0].startswith("forbidden import"), found
