"""Browser tests: Debian's chromium driven by Playwright, servers started and stopped here."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import pytest

from kinefuse.app.cli import main

CHROMIUM = Path("/usr/bin/chromium")


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """Chromium for one test module. Playwright's sync API keeps an event loop running in this
    thread while it is open, so it is closed with its module: later tests' ``asyncio.run`` works."""
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} not found (install Debian's chromium: apt-get install chromium)")
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox"])
        yield b
        b.close()


@pytest.fixture
def page(browser) -> Iterator[Any]:
    """A page that records console errors and page errors in ``page.errors``."""
    ctx = browser.new_context(viewport={"width": 1280, "height": 760})
    pg = ctx.new_page()
    pg.errors = []
    pg.on("console", lambda m: pg.errors.append(m.text) if m.type == "error" else None)
    pg.on("pageerror", lambda e: pg.errors.append(str(e)))
    pg.set_default_timeout(10_000)
    yield pg
    ctx.close()


@pytest.fixture(scope="session")
def calibrated_session(tmp_path_factory, shared_data) -> Path:
    """A simulated walk after 5 s of wand waving, calibrated, fused with best and paper (stored)."""
    out = tmp_path_factory.mktemp("browser") / "walk.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    # 5 s of wand at the default depth rate: a calibration graded good (about 2.5 mm)
    assert main(["simulate", "--clip", str(clip), "--calibration-seconds", "5", "--seed", "1",
                 "--out", str(out)]) == 0  # fmt: skip
    assert main(["calibrate", str(out), "--store"]) == 0
    for m in ("best", "paper"):
        assert main(["fuse", str(out), "--method", m, "--store"]) == 0
    return out


class LoopThread:
    """An asyncio loop in a thread, for servers the synchronous Playwright API talks to."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def run(self, coro: Any, timeout: float = 20.0) -> Any:
        fut: Future[Any] = asyncio.run_coroutine_threadsafe(coro, self.loop)
        return fut.result(timeout)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@pytest.fixture
def loop_thread() -> Iterator[LoopThread]:
    lt = LoopThread()
    yield lt
    lt.close()
