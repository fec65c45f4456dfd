"""The `ctrplan serve` page, drawn with viser: the anatomy (plan.html's names and colours), the robot's
backbone, the target with a transform gizmo, the path coloured by clearance, the result panel, a slider
along the path, the tissue controls and the buttons that write ``plan --out``'s files.

Planning runs in one thread of its own (`Page.request`): while the target is dragged, the newest
target is planned as soon as the previous plan is drawn (the latest request wins, none queue up);
a plan from the JSON API is drawn too. Answers are drawn in the order they were planned. A roadmap
path is drawn the moment the query finds it (a `Sketch`: the planning model's backbones), then again
from the exact model's states with the verdict -- unless a newer target is already waiting, when it
is not validated at all. The anatomy is drawn from display meshes (`ctrplan.viz.display_mesh`).
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import viser

from ctrplan.serve.render import (
    clearance_rgb,
    first_camera,
    hex_rgb,
    legend_html,
    ray_hit,
    result_markdown,
    segment_colours,
    segments,
    sketch_markdown,
)
from ctrplan.serve.session import Answer, PlanSession, Sketch
from ctrplan.viz.display_mesh import display_mesh
from ctrplan.viz.style import TARGET_COLOR, scene_colors

#: Width of the drawn backbone (mm) and of the tip path (mm); the gizmo's size (mm).
BACKBONE_MM = 1.5
TIP_PATH_MM = 0.6
GIZMO_MM = 24.0
#: The exact clearances of an answer are measured once no new target came for this long (s): a
#: measurement (a few hundred ms) never delays the path of a target that is still being dragged.
SETTLE_S = 0.4
#: What the panel says below a roadmap's "no path" while the single-query planner looks for one.
FALLING_BACK = "\n\n*planning from scratch (the single-query planner) ...*"
#: An obstacle much larger than the target region's neighbourhood (the face plate) is drawn faint.
BACKDROP_MM = 150.0


class Page:
    """The page of one `PlanSession` on a viser server (see the module docstring)."""

    def __init__(self, server: viser.ViserServer, session: PlanSession, out: Path, scene_file: Path):
        self.server, self.session, self.out, self.scene_file = server, session, out, scene_file
        self._pending: tuple[np.ndarray, float] | None = None
        self._asked: tuple[np.ndarray, float] | None = None  # the last request
        self._wake = threading.Condition()
        self._draw_lock = threading.Lock()
        self._drawn = 0
        self._shown: Answer | None = None
        self._saves = 0
        self._stop = False
        self._setup_scene()
        self._setup_gui()
        self._thread = threading.Thread(target=self._planner, name="ctrplan-serve-planner", daemon=True)
        self._thread.start()

    # ---- layout -----------------------------------------------------------------------------------
    def _setup_scene(self) -> None:
        sc, srv = self.session.scene, self.server
        srv.scene.set_up_direction("+y")
        srv.gui.configure_theme(control_width="large", show_share_button=False)
        # Light that costs little per pixel: a browser without a GPU draws every frame in software,
        # where viser's defaults (an environment map, shadow-casting lights) took 200 ms a frame of
        # the skull base against 70 ms without them (docs/benchmarks.md)
        srv.scene.configure_environment_map(None)
        srv.scene.configure_default_lights(True, cast_shadow=False)
        srv.scene.add_light_ambient("/light", intensity=1.0)
        colours = scene_colors(sc.obstacles)
        self.meshes = {}
        for o in sc.obstacles:
            vertices, faces = display_mesh(o)
            big = float(np.ptp(vertices, axis=0).max()) > BACKDROP_MM
            h = srv.scene.add_mesh_simple(
                f"/anatomy/{o.name}", vertices.astype(np.float32), faces.astype(np.uint32),
                color=hex_rgb(colours[o.name]),
                opacity=0.08 if big else 0.45, side="front", flat_shading=True, cast_shadow=False,
                receive_shadow=False, visible=not big)
            h.on_click(self._clicked)
            self.meshes[o.name] = h
        self.legend = [(o.name, colours[o.name]) for o in sc.obstacles]
        t = self.session.target
        self.gizmo = srv.scene.add_transform_controls("/target", scale=GIZMO_MM, disable_rotations=True,
                                                      position=tuple(t.center), depth_test=False)
        self.ball = srv.scene.add_icosphere("/target/region", radius=float(t.tolerance_mm),
                                            color=hex_rgb(TARGET_COLOR), opacity=0.55)
        self.gizmo.on_update(lambda _e: self._dragged())
        start = self.session.ctx.checker.forward(sc.start[None])
        self.start_backbone = sc.to_scene(start.positions_mm[0])
        self._draw_backbone(self.start_backbone, None)
        position, look = first_camera(self.start_backbone[-1], t.center, np.array([0.0, 1.0, 0.0]))
        cam = srv.initial_camera
        cam.position, cam.look_at, cam.far, cam.near = tuple(position), tuple(look), 5000.0, 0.5

    def _setup_gui(self) -> None:
        gui, t = self.server.gui, self.session.target
        gui.add_markdown(f"**ctrplan** &middot; {self.session.scene.name} &middot; drag the target's arrows, "
                         "or click a structure to put the target on its surface")
        self.vector = gui.add_vector3("target (mm)", tuple(np.round(t.center, 2)), step=0.1)
        self.vector.on_update(lambda e: e.client is not None and self._typed())
        self.tolerance = gui.add_number("tolerance (mm)", float(t.tolerance_mm), min=0.1, max=20.0, step=0.1)
        self.tolerance.on_update(lambda e: e.client is not None and self._typed())
        self.result = gui.add_markdown("planning the scene's target ...")
        self.slider = gui.add_slider("along the path", 0, 1, 1, 1, disabled=True)
        self.slider.on_update(lambda e: e.client is not None and self._show_state())
        save = gui.add_button("write path.json + trajectory.csv")
        save.on_click(lambda event: self._save(event.client))
        self.saved = gui.add_markdown("")
        with gui.add_folder("tissue shift", expand_by_default=False):
            names = [o.name for o in self.session.scene.obstacles]
            self.structure = gui.add_dropdown("structure", names, initial_value=names[-1])
            self.shift = gui.add_vector3("translation (mm)", (0.0, 0.0, 0.0), step=0.5)
            move = gui.add_button("move it")
            move.on_click(lambda _e: self._move())
            self.moved = gui.add_markdown("")
        with gui.add_folder("structures", expand_by_default=False):
            gui.add_html(legend_html(self.legend, TARGET_COLOR))
            backdrops = [name for name, h in self.meshes.items() if not h.visible]
            if backdrops:  # a plate far larger than the anatomy hides it and, in software WebGL, takes
                # seconds a frame: off until asked for
                show = gui.add_checkbox(f"show {', '.join(backdrops)}", False)
                show.on_update(lambda _e: [setattr(self.meshes[n], "visible", show.value) for n in backdrops])

    # ---- planning ---------------------------------------------------------------------------------
    def request(self, centre: np.ndarray, tolerance_mm: float) -> None:
        """Plan ``centre`` with ``tolerance_mm`` as soon as the planner is free (a newer request
        replaces one not started)."""
        with self._wake:
            self._pending = self._asked = (np.asarray(centre, dtype=float), float(tolerance_mm))
            self._wake.notify()

    def close(self) -> None:
        with self._wake:
            self._stop = True
            self._wake.notify()
        self._thread.join(timeout=5.0)

    def _planner(self) -> None:
        while True:
            with self._wake:
                while self._pending is None and not self._stop:
                    self._wake.wait()
                if self._stop:
                    return
                centre, tol = self._pending
                self._pending = None
            try:
                self._plan(centre, tol)
            except Exception as exc:  # noqa: BLE001 - a failed plan is shown, the page lives on
                self.result.content = f"**planning failed**: {type(exc).__name__}: {exc}"

    def _plan(self, centre: np.ndarray, tol: float) -> None:
        """Plan and draw; where the roadmap has no path, say so at once, then -- unless the target
        has moved on meanwhile -- plan from scratch (seconds) and draw that; once the target rests,
        measure the exact clearances and show them."""
        answer = self.session.plan(centre, tol, use="roadmap", clearances=False, preview=self._sketched)
        if answer is None:  # a newer target came before the validation: it is planned next
            return
        fall_back = not answer.result.solved and self.session.live is not None and self._idle()
        self.show(answer, note=FALLING_BACK if fall_back else "")  # one update: never "no path" alone
        if fall_back:
            answer = self.session.plan(centre, tol, use="single", clearances=False)
            self.show(answer)
        if answer.result.dense is not None and self._idle(SETTLE_S):
            measured = self.session.measure(answer, stop=lambda: not self._idle())
            if measured is not None:  # else a newer target came: it is planned at once
                self.show(measured, again=True)

    def _sketched(self, sketch: Sketch) -> bool:
        """Draw a roadmap path before its validation; whether to validate it (no newer target)."""
        self.show_sketch(sketch)
        return self._idle()

    def _idle(self, wait_s: float = 0.0) -> bool:
        """No newer target waiting (after ``wait_s`` seconds, if none came meanwhile)."""
        with self._wake:
            if self._pending is None and wait_s > 0:
                self._wake.wait(wait_s)
            return self._pending is None and not self._stop

    def _dragged(self) -> None:
        centre = np.asarray(self.gizmo.position, dtype=float)
        tol = float(self.tolerance.value)
        if self._asked is not None and np.array_equal(centre, self._asked[0]) and tol == self._asked[1]:
            return  # the release repeats the drag's last step: planned (or being planned) already
        self.vector.value = tuple(np.round(centre, 2))  # a server-side change: no callback of ours runs
        self.request(centre, tol)

    def _typed(self) -> None:
        centre = np.asarray(self.vector.value, dtype=float)
        self.gizmo.position = tuple(centre)
        self.request(centre, self.tolerance.value)

    def _clicked(self, event) -> None:
        name = event.target.name.rsplit("/", 1)[-1]
        o = next(o for o in self.session.scene.obstacles if o.name == name)
        m = o.to_trimesh()
        hit = ray_hit(np.asarray(m.vertices), np.asarray(m.faces), np.asarray(event.ray_origin),
                      np.asarray(event.ray_direction))
        if hit is not None:
            self.gizmo.position = tuple(hit)
            self.vector.value = tuple(np.round(hit, 2))
            self.request(hit, self.tolerance.value)

    def _move(self) -> None:
        try:
            record = self.session.move(self.structure.value, np.asarray(self.shift.value, dtype=float))
        except Exception as exc:  # noqa: BLE001 - shown, not raised
            self.moved.content = f"**not moved**: {exc}"
            return
        self.show_move(record)
        self.request(self.session.target.center, self.tolerance.value)

    # ---- drawing ----------------------------------------------------------------------------------
    def show_move(self, record: dict) -> None:
        """Draw a moved structure at its new place and say what the repair did."""
        name = record["structure"]
        self.meshes[name].position = tuple(record["shift_mm"])
        rep = record.get("repair")
        text = f"**{name}** now {np.round(record['shift_mm'], 2).tolist()} mm from its place"
        if rep:
            text += (f"; roadmap repaired in {1e3 * rep['seconds']['total_s']:.0f} ms: "
                     f"{rep['suspect']['nodes']:,} of {rep['total']['nodes']:,} states and "
                     f"{rep['suspect']['edges']:,} of {rep['total']['edges']:,} edges near it to check "
                     f"when a path uses them, {rep['reopened']['nodes']:,} / {rep['reopened']['edges']:,} "
                     "blocked ones reopened")
        self.moved.content = text

    def show(self, answer: Answer, move_target: bool = False, again: bool = False, note: str = "") -> None:
        """Draw an answer (unless a newer one is drawn already): path, result, slider; with
        ``move_target`` (a target set elsewhere: the API) the target too. A dragged target is never
        moved back to where an older answer was planned. ``again``: the answer drawn last, now with
        its clearances: the panel only. ``note``: markdown appended to the panel in the same update."""
        with self._draw_lock:
            if again and answer.number == self._drawn:
                moved = {o.name: self.session.shift_of(o.name) for o in answer.scene.obstacles}
                self.result.content = result_markdown(answer.to_json(), answer.plan_result.planner, moved)
                return
            if answer.number <= self._drawn:
                return
            self._drawn, self._shown = answer.number, answer
            doc = answer.to_json()
            with self.server.atomic():
                self.ball.radius = float(doc["tolerance_mm"])
                if move_target:
                    self.gizmo.position = tuple(doc["target_mm"])
                    self.vector.value = tuple(np.round(doc["target_mm"], 2))
                self._draw_path(answer)
                moved = {o.name: self.session.shift_of(o.name) for o in answer.scene.obstacles}
                self.result.content = result_markdown(doc, answer.plan_result.planner, moved) + note
            self.server.flush()

    def show_sketch(self, sketch: Sketch) -> None:
        """Draw a path before its exact validation (unless a newer answer is drawn already): its
        tip path and last backbone coloured by the grid's clearance bound, the panel says the verdict
        is coming; the slider waits for it."""
        with self._draw_lock:
            if sketch.number <= self._drawn:
                return
            with self.server.atomic():
                self.ball.radius = float(sketch.target.tolerance_mm)
                self._draw_states(sketch.backbones_mm, sketch.capsule_clearance_mm)
                self.slider.disabled = True
                self.result.content = sketch_markdown(sketch.number, "roadmap", sketch.target.center,
                                                      sketch.target.tolerance_mm)
            self.server.flush()

    def _draw_path(self, answer: Answer) -> None:
        dense = answer.result.dense
        if dense is None:
            self.server.scene.remove_by_name("/path")
            self.slider.disabled = True
            self._draw_backbone(self.start_backbone, None)
            return
        self._backbones = answer.scene.to_scene(dense.exact.positions_mm)
        self._per_capsule = answer.capsule_clearance_mm
        self._draw_states(self._backbones, self._per_capsule)
        k = len(self._backbones) - 1
        self.slider.max, self.slider.disabled = k, False
        self.slider.value = k

    def _draw_states(self, backbones: np.ndarray, per_capsule: np.ndarray) -> None:
        """The tip path of backbones (K, P, 3) (scene frame, mm) coloured by the clearance of each
        step (the smaller of its states', from the per-capsule clearances (K, P-1) mm) and the last
        backbone by its capsules'."""
        per_state = per_capsule.min(axis=1)
        seg_clear = np.minimum(per_state[1:], per_state[:-1])
        self.server.scene.add_line_segments("/path/tip", segments(backbones[:, -1]),
                                            segment_colours(clearance_rgb(seg_clear)), thickness=TIP_PATH_MM)
        self._draw_backbone(backbones[-1], per_capsule[-1])

    def _show_state(self) -> None:
        if self._shown is None or self._shown.result.dense is None:
            return
        k = int(np.clip(self.slider.value, 0, len(self._backbones) - 1))
        self._draw_backbone(self._backbones[k], self._per_capsule[k])

    def _draw_backbone(self, points: np.ndarray, clearance: np.ndarray | None) -> None:
        ok = np.isfinite(points).all(axis=1)
        p = points[ok]
        colours = np.tile(np.array([60, 60, 70], np.uint8), (len(p) - 1, 1)) if clearance is None else \
            clearance_rgb(clearance[ok[1:] & ok[:-1]])
        self.server.scene.add_line_segments("/robot", segments(p), segment_colours(colours),
                                            thickness=BACKBONE_MM)

    def _save(self, client) -> None:
        self._saves += 1
        folder = self.out / f"plan_{self._saves:03d}"
        try:
            written = self.session.save(folder, self.scene_file)
        except Exception as exc:  # noqa: BLE001 - shown, not raised
            self.saved.content = f"**not written**: {exc}"
            return
        self.saved.content = "wrote " + ", ".join(str(p) for p in written)
        for p in written:
            if p.name in ("path.json", "trajectory.csv") and client is not None:
                client.send_file_download(p.name, p.read_bytes())
