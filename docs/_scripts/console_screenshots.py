"""Screenshots of the console's views for docs/tutorials/console.md, taken from a live
``chizu serve`` in Debian's chromium (as the console's browser tests drive it).

    .venv/bin/python docs/_scripts/console_screenshots.py

Writes docs/figures/console-*.png (1280 x 800): the demo world's map with a path found by
clicking two landmarks, room A's eigenspace with a localization and with a session of
stops, a SLAM run of the aces clip shown with its map, the paper's Fig. 11(b) scene
planned, a finished mission's steps, a Prolog query and the worlds.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from examples.post_scans import flaser_scans  # noqa: E402
from tests.conftest import LiveServer  # noqa: E402
from tests.console.test_console import ARGS, CHROMIUM, SMALL_EIGENSPACE  # noqa: E402

OUT = ROOT / "docs" / "figures"


def wait(c: httpx.Client, job: dict) -> None:
    while c.get(f"/jobs/{job['id']}").json()["status"] in ("queued", "running"):
        time.sleep(0.5)


def main() -> None:
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as d:
        srv = LiveServer(Path(d) / "data", demo=True)
        try:
            with httpx.Client(base_url=srv.url, timeout=600) as c:
                c.post("/worlds", json={"name": "room_a", "template": "room_a"})
                learn = {"learning_strategy": None}
                wait(c, c.post("/worlds/room_a/eigenspace", json=learn).json())
                c.post("/worlds", json={"name": "room_a_coarse", "template": "room_a"})
                wait(c, c.post("/worlds/room_a_coarse/eigenspace",
                               json=SMALL_EIGENSPACE).json())
                c.post("/worlds", json={"name": "room11b", "template": "fig11b"})
                c.post("/worlds", json={"name": "mission", "template": "mission"})
                wait(c, c.post("/worlds/mission/eigenspace", json=SMALL_EIGENSPACE).json())
                wait(c, c.post("/worlds/mission/missions", json={"seed": 3}).json())
                c.post("/worlds", json={"name": "aces"})
                rid = c.post("/worlds/aces/slam-runs", json={"method": "graph"}).json()["id"]
                scans = flaser_scans(str(ROOT / "examples" / "aces-clip.clf"), 40.0)
                for i in range(0, len(scans), 100):
                    c.post(f"/worlds/aces/slam-runs/{rid}/scans",
                           json={"scans": scans[i:i + 100]}).raise_for_status()
            with sync_playwright() as p:
                b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
                page = b.new_page(viewport={"width": 1280, "height": 800})
                page.goto(srv.url + "/")
                page.wait_for_selector("body[data-ready=true]")
                page.locator('.landmark[data-id="rn0a"]').click()
                page.locator('.landmark[data-id="rs3b"]').click()
                page.wait_for_selector("[data-testid=path-summary]")
                page.screenshot(path=OUT / "console-map-path.png")

                page.select_option("#world-select", "room_a")
                page.wait_for_selector("#layer-eigen circle", state="attached")
                page.check("#layers input[data-layer=coverage]")
                page.check("#layers input[data-layer=eigen]")
                page.click("#localize-form button")
                page.wait_for_selector("#localize-result p[class^=state-]", timeout=60_000)
                page.screenshot(path=OUT / "console-eigenspace.png")

                # a session where one turn is not enough: a coarse eigenspace
                page.select_option("#world-select", "room_a_coarse")
                page.wait_for_function("document.body.dataset.world === 'room_a_coarse'")
                for k, v in (("x", 1.3), ("y", 1.2), ("theta", 0.5)):
                    page.fill(f"#localize-form input[name={k}]", str(v))
                page.click("#session-start")
                page.wait_for_selector("#localize-result p[data-state=x]")
                for _ in range(3):
                    n = page.locator("#session-stops li").count()
                    page.click("#session-stop")
                    page.wait_for_selector(f"#session-stops li:nth-child({n + 1})",
                                           timeout=60_000)
                    if page.locator("#session-move").is_disabled():
                        break  # Z
                    page.click("#session-move")
                    page.wait_for_selector("#localize-result p[data-move]")
                page.locator("#session-stops").scroll_into_view_if_needed()
                page.screenshot(path=OUT / "console-session.png")

                page.select_option("#world-select", "aces")
                page.wait_for_function("document.body.dataset.world === 'aces'")
                page.click(f'#slam-runs button[data-run="{rid}"]')
                page.wait_for_selector(f"#slam-runs[data-shown='{rid}']")
                page.locator("#slam-runs").scroll_into_view_if_needed()
                page.screenshot(path=OUT / "console-slam-run.png")

                page.select_option("#world-select", "room11b")
                page.wait_for_function(
                    "document.body.dataset.world === 'room11b'")
                page.fill("#plan-body", (ROOT / "examples" / "scene.json").read_text())
                page.click("#plan-form button")
                page.wait_for_selector("[data-testid=plan-summary]")
                page.locator("#plan-result").scroll_into_view_if_needed()
                page.screenshot(path=OUT / "console-viewpoint-plan.png")

                page.goto(srv.url + "/#/mission")
                page.wait_for_selector("body[data-ready=true]")
                page.select_option("#world-select", "mission")
                page.click("#mission-replay")
                page.wait_for_selector("#mission-steps[data-state=replayed]")
                page.screenshot(path=OUT / "console-mission.png")

                page.goto(srv.url + "/#/query")
                page.wait_for_selector("body[data-ready=true]")
                page.fill("#goal", "reachable(c1, To, P, Method), P > 0.9")
                page.click("#query-form button")
                page.wait_for_selector("#solutions")
                page.screenshot(path=OUT / "console-query.png")

                page.goto(srv.url + "/#/worlds")
                page.wait_for_selector("#worlds-table tbody tr")
                page.screenshot(path=OUT / "console-worlds.png")
                b.close()
        finally:
            srv.stop()
    print(f"wrote {OUT}/console-*.png")


if __name__ == "__main__":
    main()
