"""Make the README's screenshots: the live viewer, the replay viewer and the HTML report.

    python studies/readme_screenshots.py [--out docs/img]

Simulates 8 s of the bundled clip (CMU 01_01) watched by 4 sensors after 12 s of wand waving,
calibrates (``full``), fuses with ``best``, ``paper`` and ``best-live`` (stored in the session),
then, with Debian's chromium (/usr/bin/chromium) driven by Playwright:

* ``viewer.png``: the live viewer of a Publisher fed at 30 Hz from that session
  (:func:`kinefuse.live.viewer.feed.publish_session`), two sensors' raw skeletons switched on;
* ``replay.png``: ``kinefuse view`` of the session, paused mid-clip, truth overlaid;
* ``report.png``: the top of the ``report.html`` that ``kinefuse evaluate --out`` writes.

The session and report go to a temporary folder; only the three PNGs are written to ``--out``.
``--smoke``: the three pictures into a temporary folder (CI runs it).
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
import threading
from pathlib import Path

from kinefuse.app.cli import main as cli
from kinefuse.app.workflows.simulate import demo_clip_path
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.bus import Publisher
from kinefuse.live.viewer import live_viewer, serve
from kinefuse.live.viewer.feed import publish_session
from kinefuse.live.viewer.replay import ReplaySource
from kinefuse.live.viewer.session_data import load_session_view

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"
VIEWPORT = {"width": 1440, "height": 820}


def make_session(folder: Path) -> Path:
    s = folder / "session.sqlite"
    ok = cli(["simulate", "--clip", str(demo_clip_path()), "--seconds", "8",
              "--calibration-seconds", "12", "--seed", "0", "--out", str(s)]) == 0  # fmt: skip
    ok = ok and cli(["calibrate", str(s), "--store"]) == 0
    for m in ("best", "paper", "best-live"):
        ok = ok and cli(["fuse", str(s), "--method", m, "--store"]) == 0
    if not ok:
        raise SystemExit("could not build the session for the screenshots")
    return s


class Loop:
    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def run(self, coro):  # type: ignore[no-untyped-def]
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(60)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)


def main() -> int:
    ap = argparse.ArgumentParser(description="write the README's screenshots")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img")
    ap.add_argument("--smoke", action="store_true", help="into a temporary folder")
    args = ap.parse_args()
    if args.smoke:
        args.out = Path(tempfile.mkdtemp(prefix="readme_screenshots_"))
    from playwright.sync_api import sync_playwright

    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        session = make_session(Path(tmp))
        with SessionStore.open(session) as st:
            live_view = load_session_view(st, with_truth=False)
            replay_view = load_session_view(st)
        report_dir = Path(tmp) / "evaluation"
        if cli(["evaluate", str(session), "--out", str(report_dir)]) != 0:
            raise SystemExit("evaluate failed")
        lp = Loop()
        pub = Publisher()
        live_cm = live_viewer(pub, port=0)
        replay_cm = serve(ReplaySource(replay_view, name=session.name), port=0)

        async def start() -> tuple[int, int, asyncio.Task[int]]:
            feed = asyncio.create_task(publish_session(pub, live_view))
            return await live_cm.__aenter__(), await replay_cm.__aenter__(), feed

        live_port, replay_port, feed = lp.run(start())
        try:
            with sync_playwright() as p:
                b = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
                pg = b.new_page(viewport=VIEWPORT)
                pg.goto(f"http://127.0.0.1:{live_port}/")
                pg.wait_for_selector("#layers input[data-layer='1:k0']")
                pg.check("#layers input[data-layer='1:k0']")
                pg.check("#layers input[data-layer='1:k1']")
                pg.wait_for_timeout(2500)
                pg.screenshot(path=str(args.out / "viewer.png"))

                pg.goto(f"http://127.0.0.1:{replay_port}/")
                pg.wait_for_selector("#timeline:not([hidden])")
                pg.wait_for_function("document.getElementById('frame-counter').textContent !== '–'")
                target = replay_view.n_frames // 2
                pg.eval_on_selector(
                    "#scrub",
                    "(el, i) => { el.value = String(i); el.dispatchEvent(new Event('input')); }",
                    target,
                )
                pg.wait_for_function(
                    f"document.getElementById('frame-counter').textContent === '{target}'"
                )
                pg.check("#layers input[data-layer='0:paper']")
                pg.wait_for_timeout(500)
                pg.screenshot(path=str(args.out / "replay.png"))

                rp = b.new_page(viewport={"width": 1200, "height": 1500})
                rp.goto((report_dir / "report.html").as_uri())
                rp.screenshot(path=str(args.out / "report.png"))
                b.close()
        finally:

            async def stop() -> None:
                feed.cancel()
                await live_cm.__aexit__(None, None, None)
                await replay_cm.__aexit__(None, None, None)

            lp.run(stop())
            lp.close()
    for name in ("viewer.png", "replay.png", "report.png"):
        print(f"wrote {args.out / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
