"""The viewer with two people in the room: the server's per-person live fusion of a hand-made
scene of two real clips (``tests/people_scene.py``: a bystander crossing in front of the subject)
published at 30 Hz to the live viewer; the page lists every person with their id, marks the
subject, and draws the bystander."""

from __future__ import annotations

import asyncio
import contextlib
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from kinefuse.live.bus import FusedFrame, Publisher
from kinefuse.live.server.fusion_loop import FrameFusion
from kinefuse.live.viewer import live_viewer

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from people_scene import RATE, observation, two_people


def _frames(shared_data: Path) -> list[FusedFrame]:
    """The published frames of the scene's crossing (1.5 to 4 s), fused per person."""
    lab = two_people(shared_data)
    ff = FrameFusion("best-live")
    ff.set_poses(lab["poses"])
    out = []
    for k in range(int(4.0 * RATE)):
        for sid in lab["streams"]:
            o = observation(lab, sid, k)
            if o is not None:
                ff.push(sid, o)
        t = (k - 1) / RATE + 0.009
        if t < 1.5:
            continue
        pos, var, status = ff.fuse(t)
        out.append(
            FusedFrame(k, t, pos, var, status, 0.01, subject=ff.subject,
                       people_m={p: f[0] for p, f in ff.people.items()})
        )  # fmt: skip
    return out


@pytest.fixture
def people_page(loop_thread, shared_data) -> Any:
    frames = _frames(shared_data)
    pub = Publisher()
    state: dict[str, Any] = {"subject": 0, "picked": []}

    def on_subject(person: int) -> None:  # what the server does: the next frames are theirs
        state["picked"].append(person)
        state["subject"] = person

    async def feed() -> None:
        # one frame of the crossing, again and again (the picture changes only when the page's
        # layers do)
        f = frames[len(frames) // 2]
        k = 0
        while True:
            pub.publish(replace(f, seq=k, subject=state["subject"]))
            k += 1
            await asyncio.sleep(1 / RATE)

    async def start() -> int:
        state["feed"] = asyncio.create_task(feed())
        state["cm"] = live_viewer(pub, host="127.0.0.1", port=0, on_subject=on_subject)
        return await state["cm"].__aenter__()

    async def stop() -> None:
        await state["cm"].__aexit__(None, None, None)
        state["feed"].cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await state["feed"]

    port = loop_thread.run(start())
    yield f"http://127.0.0.1:{port}/", state
    loop_thread.run(stop())


def test_the_page_shows_every_person_and_marks_the_subject(people_page, page) -> None:
    page.goto(people_page[0])
    page.wait_for_selector("#layers label[data-person] >> nth=1")
    people = page.locator("#layers label[data-person]")
    assert people.count() == 2
    names = sorted(people.nth(i).inner_text().strip() for i in range(2))
    assert names == ["p0 subject", "p1 make subject"]  # the button picks another subject
    assert page.locator("#layers label[data-subject]").inner_text().strip() == "p0 subject"
    # the bystander is drawn: hiding their layer changes the picture
    page.wait_for_timeout(300)
    box = page.locator("#layers label[data-person='1'] input")
    assert box.is_checked()
    shown = page.locator("#scene").screenshot()
    page.wait_for_timeout(200)
    assert page.locator("#scene").screenshot() == shown  # the same frame draws the same
    box.uncheck()
    page.wait_for_timeout(200)
    hidden = page.locator("#scene").screenshot()
    assert shown != hidden
    assert page.errors == []


def test_the_operator_picks_the_subject(people_page, page) -> None:
    url, state = people_page
    page.goto(url)
    page.wait_for_selector("#layers label[data-person] >> nth=1")
    # only the other person can be made the subject
    assert page.locator("#layers button[data-pick]").count() == 1
    page.click("#layers button[data-pick='1']")
    page.wait_for_selector("#layers label[data-subject][data-person='1']")
    assert state["picked"] == [1]
    assert page.locator("#layers label[data-person='0']").inner_text().strip() == "p0 make subject"
    assert page.errors == []
