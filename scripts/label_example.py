"""Make the segmentation example and its README figure.

    python scripts/label_example.py

Draws a label volume the way a segmentation tool would save one -- 0.7 x 0.9 x 1.2 mm voxels, the
grid turned 25 degrees and offset from the world origin -- with three structures around the open
scene's workspace: a target organ (label 1, an ellipsoid), an artery passing beside it (label 2) and a
nerve across the approach (label 3). Writes examples/segmentation/{phantom.nii.gz, names.yaml,
template.yaml}, runs `ctrplan scene from-labels` on them (examples/segmentation/phantom.yaml and
phantom_meshes/), plans the scene with the exact model and draws docs/figures/from_labels.png: the
volume's labels, and the meshes in 3-D in world millimetres with the robot at the start and the goal.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import nibabel as nib
import numpy as np
from scipy.spatial.transform import Rotation

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ctrplan.cli.app import main  # noqa: E402
from ctrplan.planning import plan  # noqa: E402
from ctrplan.scene.loader import load_scene

REPO = Path(__file__).resolve().parents[1]
FOLDER = REPO / "examples" / "segmentation"
FIGURE = REPO / "docs" / "figures" / "from_labels.png"
SPACING = np.array([0.7, 0.9, 1.2])
ROTATION = Rotation.from_rotvec(math.radians(25.0) * np.array([0.0, 0.6, 0.8])).as_matrix()
SHAPE = (100, 90, 70)
CENTRE = np.array([30.0, -35.0, 172.0])  # world mm at the middle of the grid
ORIGIN = CENTRE - ROTATION @ (SPACING * (np.array(SHAPE) - 1) / 2)
NAMES = "1: target_organ\n2: artery\n3: nerve\n"
TEMPLATE = """name: phantom
description: Structures from a label volume (examples/segmentation/phantom.nii.gz) around the open workspace.
robot: nominal
base_pose:
  position: [0.0, 0.0, 0.0]
target:
  point: [37.2, -27.2, 181.6]
  tolerance_mm: 3.0
start: [-80.0, -65.0, -10.0, 0.0, 0.0, 0.0]
planner:
  time_limit_s: 10.0
  points: 30
"""


def affine() -> np.ndarray:
    A = np.eye(4)
    A[:3, :3] = ROTATION * SPACING
    A[:3, 3] = ORIGIN
    return A


def segment_distance(p: np.ndarray, a, b) -> np.ndarray:
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = b - a
    t = np.clip((p - a) @ d / (d @ d), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * d), axis=1)


def labels() -> np.ndarray:
    ijk = np.stack(np.meshgrid(*(np.arange(n) for n in SHAPE), indexing="ij"), -1).reshape(-1, 3)
    world = ijk @ affine()[:3, :3].T + ORIGIN
    out = np.zeros(len(world), dtype=np.uint8)
    organ = np.linalg.norm((world - [40.0, -30.0, 190.0]) / [6.0, 5.0, 4.0], axis=1) <= 1.0
    out[organ] = 1
    out[segment_distance(world, [52.0, -60.0, 150.0], [52.0, 0.0, 190.0]) <= 2.5] = 2
    out[segment_distance(world, [5.0, -45.0, 160.0], [45.0, -45.0, 160.0]) <= 1.5] = 3
    return out.reshape(SHAPE)


def figure(volume: np.ndarray, scene, backbones: np.ndarray) -> None:
    fig = plt.figure(figsize=(11, 4.6))
    ax = fig.add_subplot(1, 2, 1)
    colours = {"target_organ": "tab:green", "artery": "tab:red", "nerve": "gold"}
    cmap = matplotlib.colors.ListedColormap(["#202020", *colours.values()])
    ax.imshow(volume.max(axis=2).T, origin="lower", cmap=cmap, vmin=0, vmax=3, interpolation="nearest")
    ax.set_title("label volume, largest label along k (voxel indices;\n"
                 "0.7 x 0.9 x 1.2 mm voxels, grid turned 25 deg)")
    ax.set_xlabel("i")
    ax.set_ylabel("j")
    ax3 = fig.add_subplot(1, 2, 2, projection="3d")
    for obstacle in scene.obstacles:
        v, f = obstacle.vertices, obstacle.faces
        ax3.plot_trisurf(v[:, 0], v[:, 1], v[:, 2], triangles=f, color=colours[obstacle.name], alpha=0.8,
                         linewidth=0)
    for row, colour in ((0, "tab:blue"), (-1, "black")):
        ax3.plot(*backbones[row].T, color=colour, lw=2)
    ax3.set_title("meshes from `ctrplan scene from-labels` (world mm),\n"
                  "planned robot at start (blue) and goal")
    ax3.set_xlabel("x mm")
    ax3.set_ylabel("y mm")
    ax3.set_zlabel("z mm")
    ax3.set_box_aspect((1, 1, 1))
    fig.tight_layout()
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURE, dpi=110)


def run() -> None:
    FOLDER.mkdir(parents=True, exist_ok=True)
    volume = labels()
    image = nib.Nifti1Image(volume, affine())
    image.header.set_xyzt_units("mm")
    nib.save(image, FOLDER / "phantom.nii.gz")
    (FOLDER / "names.yaml").write_text(NAMES)
    (FOLDER / "template.yaml").write_text(TEMPLATE)
    code = main(["scene", "from-labels", str(FOLDER / "phantom.nii.gz"), "--names",
                 str(FOLDER / "names.yaml"), "--template", str(FOLDER / "template.yaml"), "--out",
                 str(FOLDER / "phantom.yaml")])
    if code:
        raise SystemExit(code)
    scene = load_scene(FOLDER / "phantom.yaml")
    result = plan(scene, "cosserat", seed=0)
    print(f"planned: {result.message}")
    figure(volume, scene, scene.to_scene(result.dense.exact.positions_mm))
    print(f"wrote {FIGURE}")


if __name__ == "__main__":
    run()
