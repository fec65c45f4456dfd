"""The page's latency in a real browser: from the end of a drag of the target to the new path drawn.

Serves SCENE (with its roadmap) in this process, opens the page in headless Chromium (Debian's
``chromium``, driven by Playwright), and drags the target's gizmo N times, alternately up and down
along one axis. The page records when the pointer was released (a ``pointerup`` listener) and when
the result panel first showed the plan of the target's final place, then the next animation frame
(the path and the panel are sent together, so that frame draws the new path). Prints and writes the
latencies (ms) and a screenshot of the page after the last drag.

    python scripts/bench_page_latency.py --roadmap DIR [--scene scenes/skullbase.yaml] [--drags 12]
        [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
FLAGS = ["--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader"]
#: Records in the page: pointer releases, and every change of the panel's plan line with the frame after.
RECORDER = """() => {
  window.ups = []; window.shown = [];
  document.addEventListener('pointerup', () => window.ups.push(performance.now()), true);
  let last = '';
  new MutationObserver(() => {
    const m = document.body.innerText.match(/plan #(\\d+) \\([^)]*\\) · target \\(([^)]*)\\)/);
    if (!m || m[0] === last) return;
    last = m[0];
    const seen = performance.now();
    requestAnimationFrame(t => window.shown.push({plan: +m[1], target: m[2], seen: seen, frame: t}));
  }).observe(document.body, {subtree: true, childList: true, characterData: true});
}"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--roadmap", type=Path)
    ap.add_argument("--scene", type=Path, default=REPO / "scenes" / "skullbase.yaml")
    ap.add_argument("--drags", type=int, default=12)
    ap.add_argument("--size", default="1280x800", help="viewport WxH (px)")
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "bench_page_latency")
    args = ap.parse_args()

    from playwright.sync_api import sync_playwright

    from ctrplan.kinematics import make_backend
    from ctrplan.scene.loader import load_scene
    from ctrplan.serve.app import serving
    from ctrplan.serve.page import GIZMO_MM
    from ctrplan.serve.render import drag_arrow
    from ctrplan.serve.session import PlanSession

    sc = load_scene(args.scene)
    session = PlanSession(sc, make_backend("pinn", sc.robot), None, args.roadmap)
    args.out.mkdir(parents=True, exist_ok=True)
    latencies, records = [], []
    with serving(session, args.scene, "127.0.0.1", 0, args.out / "written") as app, sync_playwright() as p:
        browser = p.chromium.launch(executable_path=shutil.which("chromium"), args=FLAGS)
        size = tuple(int(v) for v in args.size.split("x"))
        page = browser.new_page(viewport={"width": size[0], "height": size[1]})
        page.goto(app.url)
        page.get_by_text(re.compile(r"plan #1 ")).wait_for(timeout=300_000)
        page.evaluate(RECORDER)
        page.wait_for_timeout(1000)
        cam = next(iter(app.server.get_clients().values())).camera
        for k in range(args.drags):
            axis = np.array([0.0, 1.0, 0.0])
            before = np.asarray(app.page.gizmo.position)
            drag_arrow(page, cam, size, before, GIZMO_MM * axis, 0.85, 1.0 if k % 2 == 0 else 0.7)
            time.sleep(0.3)  # the drag's last update reaches the server
            final = np.asarray(app.page.gizmo.position)
            if np.allclose(final, before):
                raise SystemExit(f"drag {k + 1} did not move the target (the gizmo hidden in this viewport?)")
            want = ", ".join(f"{v:.1f}" for v in final)
            page.wait_for_function(f"() => window.shown.some(s => s.target === '{want}' "
                                   f"&& s.frame >= window.ups[window.ups.length - 1])", timeout=120_000)
            page.wait_for_timeout(300)
            ups, shown = page.evaluate("() => [window.ups, window.shown]")
            first = next(s for s in shown if s["target"] == want and s["frame"] >= ups[-1])
            latencies.append(max(0.0, first["frame"] - ups[-1]))
            records.append({"target_mm": final.round(3).tolist(), "latency_ms": round(latencies[-1], 1),
                            "panel_ms": round(max(0.0, first["seen"] - ups[-1]), 1), "plan": first["plan"]})
            print(f"drag {k + 1}: target {want} drawn {latencies[-1]:.0f} ms after the release (panel "
                  f"{records[-1]['panel_ms']:.0f} ms)", flush=True)
        page.screenshot(path=str(args.out / "page.png"))
        browser.close()
    v = np.array(latencies)
    summary = {"drags": len(v), "median_ms": round(float(np.median(v)), 1),
               "p95_ms": round(float(np.percentile(v, 95)), 1), "max_ms": round(float(v.max()), 1),
               "load_average": list(os.getloadavg()), "viewport": args.size, "roadmap": str(args.roadmap),
               "scene": str(args.scene)}
    (args.out / "latency.json").write_text(json.dumps({"summary": summary, "drags": records}, indent=1))
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
