"""A roadmap on disk: ``roadmap.npz`` (arrays, no pickles) and ``roadmap.json`` (what it was built
for, with fingerprints of scene, robot and model, and how far the build got).

Arrays: ``q`` (N, 2N) joints of the nodes (mm, rad), node 0 the scene's start; ``tips`` (N, 3) their
tips under the planning backend (scene frame, mm); ``edges`` (E, 2) node pairs with ``lengths`` (E,)
in the planning metric (mm); ``dist`` (N,) and ``pred`` (N,): the shortest-path tree from the start
(inf / -1 where a node is not connected to it).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ctrplan.base.dataio import atomic_write
from ctrplan.base.errors import InputError
from ctrplan.collision.broadphase import geometry_key
from ctrplan.kinematics.base import Backend
from ctrplan.scene.objects import Scene

FORMAT = "ctrplan-roadmap-1"
META_FILE = "roadmap.json"
ARRAYS_FILE = "roadmap.npz"
#: Planner settings of a scene that decide which states and edges are valid.
SETTINGS_KEYS = ("margin_mm", "surrogate_margin_mm", "surrogate_coverage", "points", "resolution_mm",
                 "mm_per_rad")


def scene_fingerprint(scene: Scene) -> str:
    """Hash (hex) of what decides validity in a scene: obstacles, base pose, start, joint box and the
    planner settings of `SETTINGS_KEYS` (not the target: a roadmap answers any target)."""
    h = hashlib.sha256(geometry_key(scene.obstacles, 0.0, 0.0).encode())
    lo, hi = scene.joint_box
    for a in (scene.base_pose, scene.start, lo, hi):
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    h.update(json.dumps({k: getattr(scene.settings, k) for k in SETTINGS_KEYS}, sort_keys=True).encode())
    return h.hexdigest()


def model_fingerprint(backend: Backend) -> str:
    """``<backend>:<sha256 of the weights>`` for a backend with a model card (`Backend.model_card`),
    ``<backend>`` for one without."""
    sha = (backend.model_card or {}).get("weights_sha256")
    return f"{backend.name}:{sha}" if sha else backend.name


def fingerprints(scene: Scene, backend: Backend) -> dict[str, str]:
    return {"scene": scene_fingerprint(scene), "robot": scene.robot.fingerprint,
            "model": model_fingerprint(backend)}


@dataclass
class Roadmap:
    """Nodes, edges and the shortest-path tree from the start, with the build's record ``meta``."""

    q: np.ndarray
    tips: np.ndarray
    edges: np.ndarray
    lengths: np.ndarray
    dist: np.ndarray
    pred: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_nodes(self) -> int:
        return len(self.q)

    @property
    def connected(self) -> np.ndarray:
        """Nodes connected to the start (N,) bool."""
        return np.isfinite(self.dist)

    def path_to(self, node: int) -> np.ndarray:
        """Joints (K, 2N) of the tree path from the start to ``node``."""
        chain = [node]
        while chain[-1] != 0:
            chain.append(int(self.pred[chain[-1]]))
        return self.q[chain[::-1]]

    def save(self, folder: Path) -> None:
        """Arrays first, then the record (each file written whole or not at all)."""
        with atomic_write(folder / ARRAYS_FILE, "wb") as fh:
            np.savez(fh, q=self.q, tips=self.tips, edges=self.edges, lengths=self.lengths, dist=self.dist,
                     pred=self.pred)
        meta = {**self.meta, "format": FORMAT, "nodes": self.n_nodes, "edges": len(self.edges),
                "connected_nodes": int(self.connected.sum())}
        with atomic_write(folder / META_FILE) as fh:
            json.dump(meta, fh, indent=1)


def read_meta(folder: Path) -> dict[str, Any] | None:
    """The record of the roadmap in ``folder``; None when there is none. `InputError` for one that
    cannot be read."""
    path = Path(folder) / META_FILE
    if not path.exists():
        return None
    try:
        meta = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a roadmap record ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InputError(f"{path}: not a {FORMAT} roadmap record")
    return meta


def check_fingerprints(meta: dict[str, Any], expected: dict[str, str], folder: Path) -> None:
    """`InputError` (one line) when the roadmap in ``folder`` was built for another scene, robot or
    model than ``expected``."""
    built = meta.get("fingerprints", {})
    for what in ("scene", "robot", "model"):
        if built.get(what) != expected[what]:
            names = {"scene": meta.get("scene_name"), "robot": meta.get("robot"), "model": built.get("model")}
            raise InputError(f"{folder}: roadmap built for another {what} ({names[what]}, fingerprint "
                             f"{str(built.get(what))[:12]}, not {expected[what][:12]}); build one for this "
                             f"{what} with `ctrplan roadmap build`")


def load_roadmap(folder: Path, expected: dict[str, str] | None = None) -> Roadmap:
    """The roadmap in ``folder`` (refused with an `InputError` if it does not match ``expected``
    fingerprints, or is missing or damaged)."""
    folder = Path(folder)
    meta = read_meta(folder)
    if meta is None:
        raise InputError(f"{folder}: no roadmap here (no {META_FILE}); build one with "
                         f"`ctrplan roadmap build`")
    if expected is not None:
        check_fingerprints(meta, expected, folder)
    try:
        with np.load(folder / ARRAYS_FILE, allow_pickle=False) as z:
            arrays = {k: z[k] for k in ("q", "tips", "edges", "lengths", "dist", "pred")}
    except (OSError, ValueError, KeyError) as exc:
        raise InputError(f"{folder / ARRAYS_FILE}: cannot read the roadmap arrays ({exc})") from None
    if len(arrays["q"]) != meta.get("nodes") or len(arrays["edges"]) != meta.get("edges"):
        raise InputError(f"{folder}: {ARRAYS_FILE} does not match {META_FILE} (an interrupted write?)")
    return Roadmap(**arrays, meta=meta)
