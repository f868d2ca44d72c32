"""The live API with two people: the subject by default, every person with ``people=all``; on a
real socket, frames from the server's per-person live fusion of the two-person scene."""

from __future__ import annotations

import asyncio
import json
from dataclasses import replace
from pathlib import Path

import aiohttp
import numpy as np

from kinefuse.live.bus import FusedFrame, Publisher
from kinefuse.live.server.fusion_loop import FrameFusion
from kinefuse.live.viewer import live_viewer
from kinefuse.live.viewer.subscription_api import API_PATH
from kinefuse.live.viewer.wire import PERSON, decode_frame
from people_scene import RATE, observation, two_people


def _crossing_frame(shared_data: Path) -> FusedFrame:
    lab = two_people(shared_data)
    ff = FrameFusion("best-live")
    ff.set_poses(lab["poses"])
    k_end = int(2.6 * RATE)
    for k in range(k_end + 1):
        for sid in lab["streams"]:
            o = observation(lab, sid, k)
            if o is not None:
                ff.push(sid, o)
    t = (k_end - 1) / RATE + 0.009
    pos, var, status = ff.fuse(t)
    people = {p: f[0] for p, f in ff.people.items()}
    return FusedFrame(k_end, t, pos, var, status, 0.01, subject=ff.subject, people_m=people)


async def _first(port: int, query: str) -> tuple[int, object]:
    async with aiohttp.ClientSession() as http:
        url = f"http://127.0.0.1:{port}{API_PATH}?{query}"
        try:
            async with http.ws_connect(url) as ws:
                async for msg in ws:
                    if msg.type == aiohttp.WSMsgType.BINARY:
                        return 101, decode_frame(msg.data)
                    m = json.loads(msg.data)
                    if m["type"] == "frame":
                        return 101, m
        except aiohttp.WSServerHandshakeError as e:
            return e.status, None
    raise AssertionError("no frame")


def test_the_api_gives_the_subject_and_every_person_on_request(shared_data: Path) -> None:
    frame = _crossing_frame(shared_data)
    assert set(frame.people_m) == {0, 1}

    async def run() -> dict[str, tuple[int, object]]:
        pub = Publisher()

        async def feed() -> None:
            k = 0
            while True:
                pub.publish(replace(frame, seq=k))
                k += 1
                await asyncio.sleep(1 / RATE)

        task = asyncio.create_task(feed())
        try:
            async with live_viewer(pub, host="127.0.0.1", port=0) as port:
                queries = ("format=json", "format=json&people=all", "format=binary",
                           "format=binary&people=all", "people=everyone")  # fmt: skip
                return {q: await _first(port, q) for q in queries}
        finally:
            task.cancel()

    got = asyncio.run(run())
    default = got["format=json"][1]
    assert isinstance(default, dict) and "people_m" not in default
    every = got["format=json&people=all"][1]
    assert isinstance(every, dict) and every["subject"] == 0
    assert sorted(every["people_m"]) == ["0", "1"]
    assert every["positions_m"] == every["people_m"]["0"] == default["positions_m"]
    bystander = np.array([p if p is not None else [np.nan] * 3 for p in every["people_m"]["1"]])
    assert np.nanmin(np.linalg.norm(bystander - np.array(frame.people_m[1]), axis=1)) < 1e-5
    plain, rich = got["format=binary"][1], got["format=binary&people=all"][1]
    assert [la.kind for la in plain.layers if la.kind == PERSON] == []  # type: ignore[attr-defined]
    names = [la.name for la in rich.layers if la.kind == PERSON]  # type: ignore[attr-defined]
    assert names == ["p0 subject", "p1"]
    assert got["people=everyone"][0] == 400
