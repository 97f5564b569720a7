"""The web console in a real browser: Debian's chromium driven by Playwright against a
live ``chizu serve`` with the demo world. What a person sees is checked against what the
API answers: the demo world's landmarks, a path found by clicking two landmarks, a Prolog
query's solutions and a bad query's problem, a mission started from the page and shown
step by step while it runs; no error in the browser's console; nothing fetched from
another host (the page and /docs work offline)."""

from __future__ import annotations

import math
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from chizu.service.client import Client
from tests.conftest import ROOT, LiveServer

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
#: Chromium as root in a closed network: no sandbox, no background connections
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic"]
#: a coarse eigenspace for the mission world, so that its mission runs in seconds
SMALL_EIGENSPACE = {"camera": {"width_px": 32, "height_px": 16, "supersample": 1},
                    "learning": {"spacing_m": 1.0, "n_directions": 36},
                    "learning_strategy": None}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    srv = LiveServer(tmp_path_factory.mktemp("console") / "data", demo=True)
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        pytest.fail("chromium is missing: `make test` installs Debian's chromium")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


class Page:
    """A page at 1280 x 800 (or ``viewport``) with its console errors and every URL it
    requested."""

    def __init__(self, browser: Any, server: LiveServer,
                 viewport: tuple[int, int] = (1280, 800)) -> None:
        self.page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
        self.errors: list[str] = []
        self.requests: list[str] = []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error"
                     else None)
        self.page.on("pageerror", lambda e: self.errors.append(f"page error: {e}"))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.server = server

    def open(self, hash_: str = "") -> Any:
        self.page.goto(self.server.url + "/" + hash_)
        self.page.wait_for_selector("body[data-ready=true]", timeout=30_000)
        return self.page

    def foreign(self) -> list[str]:
        return [u for u in self.requests if not u.startswith(self.server.url)
                and not u.startswith("data:")]


@pytest.fixture
def page(browser: Any, server: LiveServer) -> Iterator[Page]:
    p = Page(browser, server)
    yield p
    p.page.close()


def api(server: LiveServer, method: str, path: str, **kw: Any) -> Any:
    r = httpx.request(method, server.url + path, timeout=60, **kw)
    r.raise_for_status()
    return r.json() if r.content else None


def learn(server: LiveServer, world: str) -> None:
    """Learn ``world``'s coarse eigenspace (:data:`SMALL_EIGENSPACE`) and wait for it."""
    with Client(server.url, timeout_s=60) as c:
        c.wait_job(c.eigenspace.post_eigenspace(world, SMALL_EIGENSPACE), timeout_s=300,
                   poll_s=0.5)


def test_the_demo_world_renders_its_landmarks_walls_and_drm(page: Page,
                                                            server: LiveServer) -> None:
    p = page.open()
    world = api(server, "GET", "/worlds/demo")
    drm = api(server, "GET", "/worlds/demo/drm")
    ids = sorted(p.locator("#layer-landmarks .landmark").evaluate_all(
        "gs => gs.map(g => g.dataset.id)"))
    assert ids == sorted(lm["id"] for lm in world["landmarks"]) and len(ids) == 22
    assert p.locator("#layer-walls line").count() == len(world["walls"])
    assert p.locator("#layer-drm line").count() == len(drm["edges"])
    # the landmarks sit where the world says: compare one circle with its coordinates
    lm = world["landmarks"][0]
    c = p.locator(f'.landmark[data-id="{lm["id"]}"] circle')
    assert float(c.get_attribute("cx")) == pytest.approx(lm["x"])
    assert float(c.get_attribute("cy")) == pytest.approx(-lm["y"])
    assert page.errors == [] and page.foreign() == []


def test_a_path_made_by_clicks_is_the_one_the_api_returns(page: Page,
                                                         server: LiveServer) -> None:
    p = page.open()
    p.locator('.landmark[data-id="rn0a"]').click()
    p.locator('.landmark[data-id="rn3b"]').click()
    p.wait_for_selector("[data-testid=path-summary]")
    want = api(server, "GET", "/worlds/demo/path", params={"from": "rn0a", "to": "rn3b"})
    drawn = p.locator("#layer-path polyline").get_attribute("data-path")
    assert drawn.split(",") == want["path"]
    steps = p.locator("#path-result ol li").all_text_contents()
    assert len(steps) == len(want["steps"])
    assert all(s.startswith(f"{st['from']} → {st['to']}: {st['method']}")
               for s, st in zip(steps, want["steps"], strict=True))
    assert page.errors == []


def test_the_map_works_by_keyboard(page: Page) -> None:
    """Landmarks are focusable: Tab reaches them and Enter picks them; the map pans and
    zooms with keys."""
    p = page.open()
    p.locator('.landmark[data-id="c0"]').focus()
    p.keyboard.press("Enter")
    p.locator('.landmark[data-id="c3"]').focus()
    p.keyboard.press("Enter")
    p.wait_for_selector("[data-testid=path-summary]")
    assert p.locator("[data-testid=path-summary]").text_content().startswith("c0")
    p.locator("#map").focus()
    before = p.locator("#map").get_attribute("viewBox")
    p.keyboard.press("+")
    p.keyboard.press("ArrowLeft")
    assert p.locator("#map").get_attribute("viewBox") != before
    p.keyboard.press("0")
    assert page.errors == []


def test_a_query_shows_its_solutions_and_a_bad_one_its_problem(page: Page,
                                                               server: LiveServer) -> None:
    p = page.open("#/query")
    goal = "reachable(rn0a, To, P, Method)"
    p.fill("#goal", goal)
    p.click("#query-form button")
    p.wait_for_selector("#solutions")
    want = api(server, "POST", "/worlds/demo/query", json={"goal": goal})
    assert p.locator("#solutions tbody tr").count() == len(want["solutions"]) > 0
    headers = p.locator("#solutions thead th").all_text_contents()
    assert set(headers) == set(want["solutions"][0])

    p.fill("#goal", "reachable(rn0a, To")
    p.click("#query-form button")
    p.wait_for_selector("#query-result .problem")
    bad = httpx.post(server.url + "/worlds/demo/query", json={"goal": "reachable(rn0a, To"})
    assert bad.status_code == 422
    text = p.locator("#query-result .problem").text_content()
    assert bad.json()["detail"] in text and "goal" in text
    # the only error the browser reports is the refused request itself
    assert [e for e in page.errors if "422" not in e] == []


def test_worlds_are_created_and_deleted_from_the_console(page: Page,
                                                        server: LiveServer) -> None:
    p = page.open("#/worlds")
    p.fill("#create-world input[name=name]", "console_w")
    p.select_option("#create-world select[name=template]", "room_a")
    p.click("#create-world button")
    p.wait_for_selector("#worlds-table a:text-is('console_w')")
    assert api(server, "GET", "/worlds/console_w")["template"] == "room_a"
    p.once("dialog", lambda d: d.accept())
    p.click("button[aria-label='Delete world console_w']")
    p.wait_for_selector("#worlds-table a:text-is('console_w')", state="detached")
    assert httpx.get(server.url + "/worlds/console_w").status_code == 404
    assert page.errors == []


def test_a_mission_started_from_the_console_shows_its_steps_live(
        page: Page, server: LiveServer) -> None:
    api(server, "POST", "/worlds", json={"name": "mission_c", "template": "mission"})
    learn(server, "mission_c")
    p = page.open("#/mission")
    p.select_option("#world-select", "mission_c")
    p.click("#mission-form button[type=submit]")
    seen_running_with_steps = False
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:
        label = p.locator("#mission-job span").text_content() or ""
        steps = p.locator("#mission-steps li").count()
        if label.strip().startswith("running") and steps > 0:
            seen_running_with_steps = True
        if label.strip().startswith(("done", "failed", "cancelled")):
            break
        time.sleep(0.2)
    assert seen_running_with_steps, "no step was shown while the mission ran"
    record = api(server, "GET", "/worlds/mission_c/mission")
    p.wait_for_function(f"document.querySelectorAll('#mission-steps li').length == "
                        f"{len(record['steps'])}")
    whats = p.locator("#mission-steps li").evaluate_all("ls => ls.map(l => l.dataset.what)")
    assert whats == [s["what"] for s in record["steps"]] and whats[-1] == "evaluation"
    # replayed: the same steps again, and a mark on the map for each step with a position
    p.click("#mission-replay")
    p.wait_for_selector("#mission-steps[data-state=replayed]")
    assert p.locator("#mission-steps li").count() == len(record["steps"])
    placed = [s for s in record["steps"] if isinstance(s["result"].get("x"), float | int)]
    assert p.locator("#layer-trajectory circle[data-step]").count() == len(placed) > 0
    assert page.errors == []


def test_localization_once_and_as_a_session_of_stops(page: Page, server: LiveServer) -> None:
    """One turn, then a session of two stops joined by the strategy's next move: the
    console's states and candidates are those the API gives for the same turns and the
    odometry between them (the previous stop's frame). The session starts where one
    turn does not localize (most turns in room A do), so that it needs the move."""
    api(server, "POST", "/worlds", json={"name": "loc_c", "template": "room_a"})
    learn(server, "loc_c")
    eigenspace = api(server, "GET", "/worlds/loc_c/eigenspace")
    directions = eigenspace["directions"]

    def turn(at: dict[str, float]) -> str:
        return api(server, "POST", "/worlds/loc_c/camera", json={
            "pose": at, "turn": directions, "format": "turn_png"})["turn_png"]

    def localized(at: dict[str, float]) -> bool:
        out = api(server, "POST", "/worlds/loc_c/localize", json={"turn_png": turn(at)})
        return bool(out["state"]["state"] == "z")

    pose = next(at for at in ({"x": round(pt["x"] + 0.3, 3), "y": round(pt["y"] + 0.2, 3),
                               "theta": th}
                              for pt in eigenspace["points"] for th in (0.5, 2.0, -2.0))
                if not localized(at))

    p = page.open()
    p.select_option("#world-select", "loc_c")
    p.wait_for_function("document.body.dataset.world === 'loc_c'")
    for k, v in pose.items():
        p.fill(f"#localize-form input[name={k}]", str(v))
    p.click("#localize-form button[type=submit]")
    p.wait_for_selector("#localize-result p[data-state]")
    want = api(server, "POST", "/worlds/loc_c/localize", json={"turn_png": turn(pose)})
    assert p.locator("#localize-result p[data-state]").get_attribute("data-state") == \
        want["state"]["state"]
    assert p.locator("#layer-localization .candidate").count() == len(want["candidates"])

    p.click("#session-start")
    p.wait_for_selector("#localize-result p[data-state=x]")
    p.click("#session-stop")
    p.wait_for_selector("#session-stops li:nth-child(1)")
    p.click("#session-move")
    p.wait_for_selector("#localize-result p[data-move], #localize-result p:has-text('no move')")
    second = {k: float(p.locator(f"#localize-form input[name={k}]").input_value())
              for k in ("x", "y", "theta")}
    p.click("#session-stop")
    p.wait_for_selector("#session-stops li:nth-child(2)")
    got = p.locator("#session-stops li").evaluate_all("ls => ls.map(l => l.dataset.state)")
    sid = api(server, "POST", "/worlds/loc_c/localization-sessions")["id"]
    stops = f"/worlds/loc_c/localization-sessions/{sid}/stops"
    first = api(server, "POST", stops, json={"turn_png": turn(pose)})
    c, s_ = math.cos(pose["theta"]), math.sin(pose["theta"])
    dx, dy = second["x"] - pose["x"], second["y"] - pose["y"]
    odo = {"dx": c * dx + s_ * dy, "dy": -s_ * dx + c * dy,
           "dtheta": math.remainder(second["theta"] - pose["theta"], math.tau)}
    then = api(server, "POST", stops, json={"turn_png": turn(second), "odometry": odo})
    assert got[0] == "z" or second != pose  # not localized: the strategy moved it
    assert got == [first["state"]["state"], then["state"]["state"]]
    assert p.locator("#layer-localization .candidate").count() == len(then["candidates"])
    assert page.errors == []


def test_the_jobs_list_follows_every_worlds_jobs_live(page: Page, server: LiveServer) -> None:
    """The jobs view lists the jobs once, then the service-wide job events keep it
    current (no polling): a job started over the API appears, moves and ends; one
    cancelled by its button ends cancelled."""
    api(server, "POST", "/worlds", json={"name": "jobs_c", "template": "room_a"})
    p = page.open("#/jobs")
    p.wait_for_selector("#jobs-table[data-live=true]")
    job = api(server, "POST", "/worlds/jobs_c/eigenspace", json=SMALL_EIGENSPACE)
    row = f"#jobs-table tr[data-job='{job['id']}']"
    p.wait_for_selector(f"{row}[data-status=done]", timeout=300_000)
    assert p.locator(f"{row} progress").evaluate("e => e.value") == 1
    big = {**SMALL_EIGENSPACE, "learning": {"spacing_m": 0.25, "n_directions": 72}}
    job = api(server, "POST", "/worlds/jobs_c/eigenspace", json=big)
    row = f"#jobs-table tr[data-job='{job['id']}']"
    p.wait_for_selector(row)
    p.click(f"{row} button")
    p.wait_for_selector(f"{row}[data-status=cancelled]", timeout=120_000)
    assert api(server, "GET", f"/jobs/{job['id']}")["status"] == "cancelled"
    gets = [u for u in page.requests if u.endswith("/jobs")]
    assert len(gets) == 1, gets  # listed once: the rest came as events
    assert page.errors == []


def test_a_committed_map_is_drawn_with_its_unknown_regions(page: Page, server: LiveServer,
                                                           tmp_path: Path) -> None:
    """A map made by ``chizu slam`` from the aces clip, uploaded to a world: its grid is
    drawn where map.yaml puts it, and each unknown region the knowledge base holds is a
    circle of its area at its centre."""
    from typer.testing import CliRunner

    from chizu.service.cli import app as cli

    res = CliRunner().invoke(cli, ["slam", str(ROOT / "examples" / "aces-clip.clf"),
                                   "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    api(server, "POST", "/worlds", json={"name": "aces_c"})
    api(server, "PUT", "/worlds/aces_c/map.chizu", content=(tmp_path / "map.chizu").read_bytes(),
        headers={"content-type": "application/octet-stream"})
    regions = api(server, "GET", "/worlds/aces_c/map")["regions"]
    assert regions  # the clip leaves parts of the building unseen
    p = page.open("#/map/aces_c")
    assert p.locator("#layer-grid image").count() == 1
    yaml = httpx.get(server.url + "/worlds/aces_c/map.yaml?max_px=2048").text
    origin = [float(v) for v in yaml.split("origin: [")[1].split("]")[0].split(",")[:2]]
    image = p.locator("#layer-grid image")
    assert float(image.get_attribute("x")) == pytest.approx(origin[0])
    circles = p.locator("#layer-regions circle")
    assert circles.count() == len(regions)
    for u in regions:
        c = p.locator(f'#layer-regions circle[data-region="{u["id"]}"]')
        assert float(c.get_attribute("cx")) == pytest.approx(u["x"])
        assert float(c.get_attribute("cy")) == pytest.approx(-u["y"])
        assert math.pi * float(c.get_attribute("r")) ** 2 == pytest.approx(u["area_m2"])
    assert f"{len(regions)} unknown regions" in p.locator("#map-info").text_content()
    assert page.errors == []


def test_a_slam_run_moves_on_the_map_as_its_scans_arrive(page: Page,
                                                          server: LiveServer) -> None:
    """Scans posted by a robot (here: the test, over the API) reach the page as live
    events: the run's trajectory grows on the map, one point a batch."""
    p = page.open()
    p.wait_for_selector("body[data-live=demo]")
    rid = api(server, "POST", "/worlds/demo/slam-runs", json={"method": "odom"})["id"]
    for i in range(4):
        scan = {"t": 0.1 * i, "odom": [0.3 * i, 0.0, 0.0], "ranges": [2.0] * 181,
                "angle_min": -1.5707963, "angle_increment": 0.0174533}
        api(server, "POST", f"/worlds/demo/slam-runs/{rid}/scans", json={"scans": [scan]})
    line = p.locator(f'#layer-trajectory polyline[data-run="{rid}"]')
    p.wait_for_function(f"document.querySelector('#layer-trajectory polyline[data-run=\"{rid}\"]')"
                        "?.dataset.scans === '4'")
    pts = line.get_attribute("points").split()
    want = api(server, "GET", f"/worlds/demo/slam-runs/{rid}/trajectory")["poses"]
    assert len(pts) == len(want) == 4
    assert [float(v) for v in pts[-1].split(",")] == pytest.approx(
        [want[-1][0], -want[-1][1]], abs=1e-6)
    assert "4 scans" in p.locator("#live-run").text_content()
    # the run appeared in the list as it started; shown, its map and trajectory are drawn
    # and follow the next scans
    button = p.locator(f'#slam-runs button[data-run="{rid}"]')
    p.wait_for_function(f"document.querySelector('#slam-runs button[data-run=\"{rid}\"]')"
                        "?.textContent.endsWith('4 scans')")
    button.click()
    p.wait_for_selector(f"#slam-runs[data-shown='{rid}']")
    assert button.get_attribute("aria-pressed") == "true"
    assert p.locator("#layer-runmap image").count() == 1
    for i in range(4, 6):
        scan = {"t": 0.1 * i, "odom": [0.3 * i, 0.0, 0.0], "ranges": [2.0] * 181,
                "angle_min": -1.5707963, "angle_increment": 0.0174533}
        api(server, "POST", f"/worlds/demo/slam-runs/{rid}/scans", json={"scans": [scan]})
    p.wait_for_selector(f"#slam-runs[data-shown='{rid}'][data-scans='6']")
    want = api(server, "GET", f"/worlds/demo/slam-runs/{rid}/trajectory")["poses"]
    pts = line.get_attribute("points").split()
    assert [float(v) for v in pts[-1].split(",")] == pytest.approx(
        [want[-1][0], -want[-1][1]], abs=1e-6) and len(pts) == 6
    button.click()  # hidden again
    p.wait_for_function("document.querySelectorAll('#layer-runmap image').length === 0")
    api(server, "DELETE", f"/worlds/demo/slam-runs/{rid}")
    assert page.errors == []


def test_a_viewpoint_plan_is_drawn_with_its_route_and_timeline(
        page: Page, server: LiveServer) -> None:
    """The paper's Fig. 11(b) scene (examples/scene.json) planned from the console: the
    groups in the order the API plans them, a pose per step on the map, the timeline
    against the time limit."""
    api(server, "POST", "/worlds", json={"name": "room11b", "template": "fig11b"})
    scene = (ROOT / "examples" / "scene.json").read_text()
    want = api(server, "POST", "/worlds/room11b/viewpoint-plan", content=scene,
               headers={"content-type": "application/json"})
    p = page.open()
    p.select_option("#world-select", "room11b")
    p.wait_for_function("document.querySelector('.world-name').textContent === 'room11b'")
    p.fill("#plan-body", scene)
    p.click("#plan-form button")
    p.wait_for_selector("[data-testid=plan-summary]")
    summary = p.locator("[data-testid=plan-summary]").text_content()
    assert summary.startswith(" → ".join(want["plan"]["groups"]))
    drawn = p.locator("#layer-plan g[data-group]").evaluate_all(
        "gs => gs.map(g => g.dataset.group)")
    assert drawn == [s["name"] for s in want["plan"]["steps"]]
    assert p.locator("#plan-result .timeline .limit").count() == 1
    assert p.locator("#plan-result .timeline .seg").count() == 2 * len(want["plan"]["steps"])
    p.fill("#plan-body", '{"robot": [1, 1]}')
    p.click("#plan-form button")
    p.wait_for_selector("#plan-result .problem")
    assert "robot" in p.locator("#plan-result .problem").text_content()
    assert [e for e in page.errors if "422" not in e] == []


def test_the_console_fits_a_tablet(browser: Any, server: LiveServer) -> None:
    """At 800 px wide the panel goes under the map and nothing scrolls sideways."""
    tablet = Page(browser, server, viewport=(800, 1100))
    p = tablet.open()
    width = p.evaluate("document.documentElement.scrollWidth")
    assert width <= 800
    map_box, panel_box = p.locator("#map").bounding_box(), p.locator(".panel").bounding_box()
    assert panel_box["y"] >= map_box["y"] + map_box["height"] - 1
    assert tablet.errors == []
    tablet.page.close()


#: axe-core's rules for WCAG 2.1 A and AA (contrast 4.5:1 among them) and its best practice
AXE_RULES = {"runOnly": {"type": "tag", "values": ["wcag2a", "wcag2aa", "wcag21a",
                                                    "wcag21aa", "best-practice"]}}


@pytest.mark.parametrize("viewport", [(1280, 800), (800, 1100)], ids=["desktop", "tablet"])
def test_every_view_passes_axe(browser: Any, server: LiveServer,
                               viewport: tuple[int, int]) -> None:
    """axe-core (the checker browsers' accessibility tools run) finds no WCAG 2.1 AA
    violation -- contrast, names, labels, roles, landmarks -- in any view, with answers
    shown: a path, a Prolog query's solutions, a problem."""
    from axe_playwright_python.sync_playwright import Axe

    page = Page(browser, server, viewport=viewport)
    p = page.open()
    p.locator('.landmark[data-id="rn0a"]').click()
    p.locator('.landmark[data-id="rn3b"]').click()
    p.wait_for_selector("[data-testid=path-summary]")
    found = {}
    for view in ("map", "worlds", "mission", "jobs", "query"):
        p.goto(f"{server.url}/#/{view}")
        p.wait_for_selector(f"#view-{view}.active")
        if view == "query":
            p.fill("#goal", "reachable(rn0a, To, P, Method)")
            p.click("#query-form button")
            p.wait_for_selector("#solutions")
            found["query with solutions"] = Axe().run(p, options=AXE_RULES).response
            p.fill("#goal", "reachable(rn0a, To")
            p.click("#query-form button")
            p.wait_for_selector("#query-result .problem")
        found[view] = Axe().run(p, options=AXE_RULES).response
    bad = {view: [(v["id"], v["help"], [n["target"] for n in v["nodes"]][:3])
                  for v in r["violations"]] for view, r in found.items() if r["violations"]}
    assert bad == {}
    assert all(r["passes"] for r in found.values())  # axe ran its rules
    page.page.close()


def test_every_control_is_reached_by_tab_and_shows_its_focus(page: Page) -> None:
    """Tab from the top of each view reaches every visible control of the page, and the
    focused one is drawn with a focus ring."""
    p = page.open()
    for view in ("map", "worlds", "mission", "jobs", "query"):
        p.goto(f"{page.server.url}/#/{view}")
        p.wait_for_selector(f"#view-{view}.active")
        controls = p.evaluate("""() => [...document.querySelectorAll(
            'a[href], button, input, select, textarea, [tabindex="0"]')]
            .filter(e => !e.disabled && e.getClientRects().length &&
                    getComputedStyle(e).visibility !== 'hidden' && !e.closest('.skip'))
            .length""")
        p.evaluate("document.activeElement.blur()")
        reached, unringed = set(), []
        for _ in range(controls + 5):
            p.keyboard.press("Tab")
            key, ring = p.evaluate("""() => {
                const e = document.activeElement, s = getComputedStyle(e);
                const c = e.querySelector && e.querySelector('circle');
                const ring = s.outlineStyle !== 'none' ||
                    (c && getComputedStyle(c).stroke !== 'none');
                const all = [...document.querySelectorAll('*')];
                return [e.tagName + '#' + all.indexOf(e), ring];
            }""")
            if key.startswith("BODY#"):  # past the last control: the browser's own UI
                continue
            reached.add(key)
            if not ring:
                unringed.append(key)
        assert len(reached) >= controls, view
        assert unringed == [], view
    assert page.errors == []


def test_the_api_docs_load_offline(page: Page, server: LiveServer) -> None:
    """/docs is Swagger UI from files the package installs: it renders the OpenAPI
    without a request to any other host."""
    page.page.goto(server.url + "/docs")
    page.page.wait_for_selector(".swagger-ui .info .title", timeout=30_000)
    assert "chizu" in page.page.locator(".swagger-ui .info .title").first.text_content()
    assert page.foreign() == [] and page.errors == []
