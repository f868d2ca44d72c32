"""The front door and the user guide: the README's shape, the guide builds, its commands run.

Every ``$ kinefuse ...`` line of a ``console`` block in the getting-started page and the
tutorials is run here, verbatim, in a fresh folder laid out like a checkout (``../shared`` and
``rigs/`` beside it), in the page's order: a tutorial that drifts from the program fails here.
"""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"

#: The pages whose ``console`` blocks are run: getting started, the tutorials, the how-to pages.
TUTORIALS = [
    DOCS / "getting-started.md",
    *sorted((DOCS / "tutorials").glob("*.md")),
    *sorted((DOCS / "howto").glob("*.md")),
]


def console_commands(page: Path) -> list[str]:
    """The ``$ ...`` lines of the page's ``console`` blocks, in order."""
    return [text for kind, text in runnable_blocks(page) if kind == "console"]


def runnable_blocks(page: Path) -> list[tuple[str, str]]:
    """The page's ``$ ...`` lines of ``console`` blocks and its ``python`` blocks, in order:
    ``("console", command)`` or ``("python", source)``."""
    out: list[tuple[str, str]] = []
    kind, lines = "", []
    for line in page.read_text().splitlines():
        if line.startswith("```"):
            if not kind:
                kind = line.strip()[3:] or "text"
                lines = []
            else:
                if kind == "python":
                    out.append(("python", "\n".join(lines)))
                kind = ""
            continue
        if kind == "console" and line.startswith("$ "):
            out.append(("console", line[2:].strip()))
        elif kind == "python":
            lines.append(line)
    return out


def test_readme_is_a_front_door() -> None:
    text = README.read_text()
    lines = text.splitlines()
    assert len(lines) <= 80, f"README.md has {len(lines)} lines (at most 80)"
    commands = lines[3:5]
    assert commands[0].endswith(".venv/bin/kinefuse demo"), commands[0]
    assert commands[1].endswith(".venv/bin/python -m pytest"), commands[1]
    for line in lines:
        if line.startswith("|"):
            for cell in line.strip("|").split("|"):
                assert len(cell.split()) <= 40, f"README cell over 40 words: {cell[:60]}..."
    assert not re.search(r"\bissues? \d+", text, re.IGNORECASE), "issue numbers in README.md"
    for link in re.findall(r"\]\(([^)#]+)", text):
        if "://" not in link:
            assert (ROOT / link).exists(), f"README links to a missing file: {link}"


#: A reference to the tracker (``issue 21``, ``issues 9 and 12``, ``#21``) or a line of run
#: history (a dated or timed rerun, "before this change"): what the studies section holds.
HISTORY = re.compile(
    r"\bissues? #?\d+|(?<![\w&/])#\d+\b|\b20\d\d-[01]\d(?:-[0-3]\d)?(?![-\dT])|\b\d\d:\d\d UTC\b"
    r"|\bbefore this change\b",
    re.IGNORECASE,
)


def guide_nav() -> list[object]:
    """The ``nav`` of mkdocs.yml."""
    import yaml

    return list(yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"])


def nav_section(title: str) -> list[dict[str, str]]:
    """The entries of one top-level section of the nav."""
    sections = [e[title] for e in guide_nav() if isinstance(e, dict) and title in e]
    assert sections, f"mkdocs.yml's nav has no section {title!r}"
    return list(sections[0])


def studies_pages() -> set[Path]:
    """The pages of the guide's "Studies" section (its nav entry in mkdocs.yml, and
    everything under ``docs/studies/``): the only place for run history."""
    pages = {DOCS / next(iter(item.values())) for item in nav_section("Studies")}
    return pages | set((DOCS / "studies").rglob("*.md"))


def test_the_nav_has_the_four_sections_and_the_studies() -> None:
    """Tutorials, how-to, reference, explanation, and the studies apart; each page once."""
    for title in ("Tutorials", "How-to", "Reference", "Explanation", "Studies"):
        assert nav_section(title), title
    pages = [v for e in guide_nav() if isinstance(e, dict) for v in e.values()]
    flat = [p for v in pages for p in ([v] if isinstance(v, str) else [*map(_page, v)])]
    assert len(flat) == len(set(flat)), "a page is listed twice in the nav"
    explanation = [_page(e) for e in nav_section("Explanation")]
    assert "how-it-works.md" in explanation and "measured.md" in explanation
    assert "studies/fusion.md" in [_page(e) for e in nav_section("Studies")]


def _page(entry: dict[str, str]) -> str:
    return next(iter(entry.values()))


def history_lines(text: str) -> list[str]:
    """The prose lines of ``text`` (fenced code blocks left out: an example file may carry a
    date) that cite an issue or log a dated rerun."""
    prose, fenced = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced:
            prose.append(line)
    return [line for line in prose if HISTORY.search(line)]


def test_history_lines_are_recognized() -> None:
    """The pattern catches what a run log says and passes what the guide says."""
    for line in (
        "the model before issue 21",
        "Issues 9 and 12 asked for it",
        "fixed in #24",
        "Rerun 2026-12-06 after the change",
        "Until 2026-12 a consensus was used",
        "on the quiet run of 07:01 UTC",
        "0, before this change",
    ):
        assert history_lines(line), line
    for line in (
        "A rerun replaces it only once the new one is complete",
        "`joints (T, 25, 3)` in metres (25 joints)",
        "created = 2026-11-21T22:50:00+00:00  # TOML offset date-time",
        "```toml\ncreated = 2026-11-21 22:50:00+00:00\n```",
        "[the protocol](protocol.md#limits), colour #fff",
    ):
        assert not history_lines(line), line


def test_every_readme_figure_links_to_its_command() -> None:
    """Each row of the README's measured table links to a page that holds the row's figure and
    a command that measures it."""
    rows = [line for line in README.read_text().splitlines() if line.startswith("| ")][1:]
    assert rows, "the README has no measured table"
    for row in rows:
        what, result, where = (cell.strip() for cell in row.strip("|").split("|"))
        link = re.search(r"\]\((docs/[^)#]+)", where)
        assert link, f"README row without a page: {what}"
        page = (ROOT / link.group(1)).read_text()
        figure = re.search(r"\d+(?:\.\d+)?", result)
        assert figure and figure.group() in page, f"{link.group(1)} lacks {result!r} ({what})"
        assert re.search(r"`(?:python (?:studies|benchmarks)/|kinefuse )", page), link.group(1)


def test_guide_pages_hold_no_run_history() -> None:
    """Issue numbers, dated reruns and who-did-what belong to the studies section, not to the
    README or the guide."""
    studies = studies_pages()
    assert DOCS / "studies.md" in studies, "the nav lost its Studies section"
    found = []
    for page in [README, *sorted(DOCS.rglob("*.md"))]:
        if page in studies:
            continue
        for line in history_lines(page.read_text()):
            found.append(f"{page.relative_to(ROOT)}: {line.strip()[:100]}")
    assert not found, "run history outside docs/studies/:\n" + "\n".join(found)


def test_the_guide_builds_strict(tmp_path: Path) -> None:
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent))
    assert mkdocs, "mkdocs is part of the test extra: pip install -e '.[test]'"
    run = subprocess.run(
        [mkdocs, "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**_env(), "NO_MKDOCS_2_WARNING": "1"},
        timeout=300,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    reference = (tmp_path / "site" / "reference" / "cli" / "index.html").read_text()
    for command in ("demo", "simulate", "calibrate", "serve", "sensor", "fuse", "analyze"):
        assert f"kinefuse {command}" in reference


def test_the_cli_reference_lists_every_command() -> None:
    from kinefuse.app.cli.cli_reference import render
    from kinefuse.app.cli.main import COMMANDS

    page = render()
    for module in COMMANDS:
        name = module.__name__.rsplit(".", 1)[1]
        assert f"## kinefuse {name}" in page
        assert "usage: kinefuse " + name in page


def _env() -> dict[str, str]:
    import os

    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


@pytest.mark.slow
@pytest.mark.parametrize("page", TUTORIALS, ids=lambda p: p.stem)
def test_every_tutorial_command_runs(
    page: Path, tmp_path: Path, shared_data: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    blocks = runnable_blocks(page)
    if page.parent.name == "tutorials":
        assert blocks, f"{page.name} shows nothing to run"
    work = tmp_path / "work"
    work.mkdir()
    (tmp_path / "shared").symlink_to(shared_data.parent)
    (work / "rigs").symlink_to(ROOT / "rigs")
    monkeypatch.chdir(work)
    namespace: dict[str, object] = {}
    for kind, command in blocks:
        if kind == "python":  # the page's blocks share one namespace, as a notebook's cells
            exec(compile(command, f"{page.name} (python block)", "exec"), namespace)
            continue
        argv = shlex.split(command)
        assert argv[0] == "kinefuse", f"{page.name}: a tutorial runs kinefuse: {command}"
        run = subprocess.run(
            argv, cwd=work, capture_output=True, text=True, env=_env(), timeout=600
        )
        assert run.returncode == 0, (
            f"{page.name}: `{command}` exited {run.returncode}:\n" + (run.stderr[-2000:])
        )
