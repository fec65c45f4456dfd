"""The `ctrplan serve` page driven in a real browser: headless Chromium (Debian's ``chromium``
package, driven by Playwright pointed at that binary -- no browser of Playwright's own). The target
is dragged by its gizmo and set through the API, a structure moved onto the path; what the page shows
(the plan, the target, the exact tip, the verdict, the clearances, the repair) must change with it.
Skipped only where no ``chromium`` is installed."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest
from playwright.sync_api import sync_playwright

from ctrplan.serve.page import GIZMO_MM
from ctrplan.serve.render import drag_arrow
from tests.independent.geometry import sphere_gap
from tests.serve.conftest import call
from tests.serve.test_api import BALL, BALL_RADIUS, TARGET, exact_backbones

CHROMIUM = shutil.which("chromium")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium on this machine (Debian: apt-get "
                                                         "install chromium): the page cannot be driven")
#: Software WebGL in a headless browser.
FLAGS = ["--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"]
W, H = 1280, 800
PLAN = re.compile(r"plan #(\d+) \((\w[\w+-]*)\) · target \((-?[\d.]+), (-?[\d.]+), (-?[\d.]+)\) mm")
TIP = re.compile(r"exact tip at \((-?[\d.]+), (-?[\d.]+), (-?[\d.]+)\) mm")


@pytest.fixture
def page(app):
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        page = browser.new_page(viewport={"width": W, "height": H})
        page.goto(app.url)
        page.get_by_text(re.compile(r"plan #1 ")).wait_for(timeout=120_000)
        wait_for_plan(page, 0)
        yield page
        browser.close()


def shown(page) -> dict:
    """What the result panel says: plan number, planner, target, verdict, exact tip, structures."""
    text = page.inner_text("body")
    plan = PLAN.search(text)
    tip = TIP.search(text)
    return {"number": int(plan.group(1)), "target": [float(plan.group(k)) for k in (3, 4, 5)],
            "solved": "solved ·" in text, "collision_free": "collision-free" in text,
            "tip": None if tip is None else [float(tip.group(k)) for k in (1, 2, 3)],
            "structures": {name: float(mm) for name, mm in re.findall(r"(ball|block)\s+([\d.]+) mm", text)},
            "text": text}


def wait_for_plan(page, after: int, timeout_ms: int = 120_000) -> dict:
    """The panel once it shows a plan numbered above ``after`` with its clearances measured (they
    follow the path once the target rests)."""
    page.wait_for_function(f"() => {{ const t = document.body.innerText, m = t.match(/plan #(\\d+) /); "
                           f"return m && +m[1] > {after} && (t.includes('nearest structures') "
                           f"|| t.includes('no path')); }}", timeout=timeout_ms)
    return shown(page)


def drag_target_up(page, app, fraction: float) -> None:
    """Drag the gizmo's y arrow (superior) from 0.85 of its length to ``fraction`` of it."""
    camera = next(iter(app.server.get_clients().values())).camera
    drag_arrow(page, camera, (W, H), np.asarray(app.page.gizmo.position), np.array([0, GIZMO_MM, 0]), 0.85,
               fraction, pause_ms=20)


def test_the_page_follows_a_dragged_target_and_one_set_through_the_api(app, page):
    first = shown(page)
    assert first["solved"] and first["collision_free"] and first["structures"]
    assert first["target"] == pytest.approx(TARGET, abs=0.05)
    for _ in range(2):  # (a drag that starts while the page still lays itself out may not take)
        drag_target_up(page, app, 1.3)  # some mm up: the target follows the gizmo
        for _ in range(50):  # the drag's last update reaches the server
            page.wait_for_timeout(100)
            if np.asarray(app.page.gizmo.position)[1] > TARGET[1] + 0.5:
                break
        else:
            continue
        break
    page.screenshot(path=str(app.page.out.parent / "after_drag.png"))
    moved_to = np.round(np.asarray(app.page.gizmo.position), 1)
    assert moved_to[1] > TARGET[1] + 0.5 and moved_to[0] == pytest.approx(TARGET[0], abs=0.05)
    after = first["number"]
    while True:  # plans of the drag's intermediate places may come first
        now = wait_for_plan(page, after)
        if now["target"] == pytest.approx(moved_to.tolist(), abs=0.06):
            break
        after = now["number"]
    assert now["tip"] != first["tip"] and now["solved"] == (now["tip"] is not None)
    assert now["structures"] != first["structures"]
    status, doc = call(app.url + "api/plan", "POST", {"target_mm": TARGET, "tolerance_mm": 3.0})
    assert status == 200 and doc["solved"]
    back = wait_for_plan(page, now["number"])
    assert back["target"] == pytest.approx(TARGET, abs=0.05)
    assert back["tip"] == pytest.approx(doc["validated"]["tip_mm"], abs=0.006)
    assert np.allclose(app.page.gizmo.position, TARGET)  # the page's target went where the API put it


def test_a_structure_moved_onto_the_path_shows_and_the_next_path_avoids_it(app, page):
    """Through the API: the ball moves onto today's path; the page says so and plans again; that
    path clears the ball at its new place (distances computed here)."""
    _, today = call(app.url + "api/plan", "POST", {"target_mm": TARGET, "tolerance_mm": 3.0})
    seen = wait_for_plan(page, shown(page)["number"] - 1)
    p, r = exact_backbones(today["path"])
    gaps = np.linalg.norm(p - BALL, axis=-1) - BALL_RADIUS - r
    k, i = np.unravel_index(np.argmin(gaps), gaps.shape)
    shift = (p[k, i] - BALL) * (1.0 - 0.5 * BALL_RADIUS / np.linalg.norm(p[k, i] - BALL))
    status, _ = call(app.url + "api/structures/ball/move", "POST", {"translation_mm": shift.tolist()})
    assert status == 200
    replanned = wait_for_plan(page, seen["number"])
    assert "tissue moved: ball by" in replanned["text"]
    assert replanned["solved"] and replanned["collision_free"], replanned["text"]
    assert replanned["tip"] is not None
    _, after = call(app.url + "api/plan", "POST", {"target_mm": TARGET, "tolerance_mm": 3.0})
    p2, r2 = exact_backbones(after["path"])
    assert sphere_gap(p, r, BALL + shift, BALL_RADIUS) < 0 <= sphere_gap(p2, r2, BALL + shift, BALL_RADIUS)
