"""The viewer page in a real browser: live status and frames, motion, replay, reconnecting."""

from __future__ import annotations

import asyncio
import contextlib
import time
from typing import Any

import pytest

from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.bus import Publisher
from kinefuse.live.viewer import live_viewer, serve
from kinefuse.live.viewer.feed import publish_session
from kinefuse.live.viewer.replay import ReplaySource
from kinefuse.live.viewer.session_data import load_session_view


class LiveRig:
    """The live viewer of a Publisher fed at 30 Hz from a recorded session, on a loop thread;
    the server can be stopped and started again on the same port while the feed goes on."""

    def __init__(self, lt: Any, view: Any) -> None:
        self.lt, self.view = lt, view
        self.pub = Publisher()
        self.port = 0
        self._cm: Any = None
        self._feed: asyncio.Task[int] | None = None

    async def _start(self) -> int:
        if self._feed is None:
            self._feed = asyncio.create_task(publish_session(self.pub, self.view))
        self._cm = live_viewer(self.pub, host="127.0.0.1", port=self.port)
        return await self._cm.__aenter__()

    async def _stop_server(self) -> None:
        await self._cm.__aexit__(None, None, None)

    async def _stop_all(self) -> None:
        if self._cm is not None:
            await self._stop_server()
        if self._feed is not None:
            self._feed.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._feed

    def start(self) -> str:
        self.port = self.lt.run(self._start())
        return f"http://127.0.0.1:{self.port}/"

    def stop_server(self) -> None:
        self.lt.run(self._stop_server())
        self._cm = None

    def close(self) -> None:
        self.lt.run(self._stop_all())


@pytest.fixture
def view(calibrated_session):
    with SessionStore.open(calibrated_session) as st:
        return load_session_view(st, with_truth=False)


@pytest.fixture
def live(loop_thread, view):
    rig = LiveRig(loop_thread, view)
    yield rig
    rig.close()


def _counter(page: Any) -> int:
    text = page.inner_text("#frame-counter")
    return int(text) if text.isdigit() else -1


def test_live_page_shows_every_sensor_and_the_frames_count_up(live, page) -> None:
    page.goto(live.start())
    page.wait_for_selector("#sensors tr.sensor-row >> nth=3")
    rows = page.locator("#sensors tr.sensor-row")
    assert rows.count() == 4
    assert [rows.nth(i).get_attribute("data-sensor") for i in range(4)] == ["k0", "k1", "k2", "k3"]
    assert "calibrated" in page.inner_text("#calibration")
    page.wait_for_function("Number(document.getElementById('frame-counter').textContent) > 0")
    first = _counter(page)
    page.wait_for_timeout(500)
    assert _counter(page) >= first + 5  # 30 Hz: about 15 frames in 0.5 s
    # the raw skeleton of each calibrated sensor is there, on a toggle
    assert page.locator("#layers input[data-layer^='1:']").count() == 4
    # two screenshots of the 3D view a second apart differ (the actor walks)
    a = page.locator("#scene").screenshot()
    page.wait_for_timeout(1000)
    b = page.locator("#scene").screenshot()
    assert a != b
    assert page.errors == []


def test_page_reconnects_without_reload_when_the_server_returns(live, page) -> None:
    page.goto(live.start())
    page.wait_for_function("Number(document.getElementById('frame-counter').textContent) > 0")
    page_id = page.evaluate("window.kinefusePageId")
    live.stop_server()
    page.wait_for_function("document.getElementById('conn').textContent.startsWith('reconn')")
    page.wait_for_timeout(1500)  # the server stays away a while
    before = _counter(page)
    live.start()  # same port
    t0 = time.monotonic()
    page.wait_for_function(
        f"Number(document.getElementById('frame-counter').textContent) > {before}",
        timeout=5000,
    )
    took = time.monotonic() - t0
    assert took < 5.0  # the acceptance: within 5 s of the server's return
    assert page.inner_text("#conn") == "connected"
    assert page.get_attribute("#conn", "data-connects") == "2"
    assert page.evaluate("window.kinefusePageId") == page_id  # the same page, not reloaded
    # the connection error of the stopped server is expected; nothing else went wrong
    assert [e for e in page.errors if "WebSocket" not in e and "ERR_CONNECTION" not in e] == []


def test_replay_scrubbing_changes_the_frame_time(calibrated_session, loop_thread, page) -> None:
    with SessionStore.open(calibrated_session) as st:
        v = load_session_view(st)
    cm = serve(ReplaySource(v, name=calibrated_session.name), port=0)
    port = loop_thread.run(cm.__aenter__())
    try:
        page.goto(f"http://127.0.0.1:{port}/")
        page.wait_for_selector("#timeline:not([hidden])")
        page.wait_for_function("document.getElementById('frame-time').textContent !== '–'")
        assert float(page.inner_text("#frame-time")) == pytest.approx(v.t_s[0], abs=1e-3)
        target = v.n_frames * 2 // 3
        page.eval_on_selector(
            "#scrub",
            "(el, i) => { el.value = String(i); el.dispatchEvent(new Event('input')); }",
            target,
        )
        page.wait_for_function(
            f"document.getElementById('frame-counter').textContent === '{target}'"
        )
        assert float(page.inner_text("#frame-time")) == pytest.approx(v.t_s[target], abs=1e-3)
        page.click("#step-fwd")
        page.wait_for_function(
            f"document.getElementById('frame-counter').textContent === '{target + 1}'"
        )
        # the truth is overlaid and the per-joint error panel filled
        assert page.is_visible("#error-section")
        mean_mm = float(page.inner_text("#error-mean-mm"))
        assert 5 < mean_mm < 150  # best on a walk: centimetres, not metres
        assert page.locator("#layers input[data-layer='0:paper']").count() == 1
        # hovering a joint names it and gives its error, and marks its row in the side panel
        joint = page.evaluate("window.kinefuseJoints()")[-1]  # the nearest one, drawn last
        box = page.locator("#scene").bounding_box()
        page.mouse.move(box["x"] + joint["x"], box["y"] + joint["y"])
        page.wait_for_selector("#tooltip:not([hidden])")
        tip = page.inner_text("#tooltip")
        name = page.evaluate("(j) => S.hello.joints[j]", joint["joint"])
        assert name in tip and "error" in tip and "mm" in tip
        assert page.inner_text("#errors tr.hot td >> nth=0") == name
        page.click("#play")
        page.wait_for_function(
            f"Number(document.getElementById('frame-counter').textContent) > {target + 3}"
        )
        assert page.errors == []
    finally:
        loop_thread.run(cm.__aexit__(None, None, None))
