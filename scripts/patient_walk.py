#!/usr/bin/env python3
"""Make the inputs of the new-user walk of issue 41: one's own patient as a label volume, in both
formats a user gets from a segmentation tool, from the skull-base anatomy.

    python scripts/patient_walk.py OUT_DIR

Rasterises every structure of scenes/skullbase.yaml (its frame: x left, y superior, z posterior) the
way a segmentation would hold it -- a shell of voxels around each surface, on a grid of
0.4 x 0.4 x 1.2 mm voxels (slices along superior), turned 10 degrees and offset from the world origin,
cropped to the anatomy around the airway -- and writes into OUT_DIR:

- ``labels.nii.gz``: the label map (NIfTI: world RAS), labels 1..16 in the scene's obstacle order;
- ``labels.seg.nrrd``: the same anatomy as 3D Slicer saves a segmentation: LPS directions and origin,
  ``Segment<N>_Name/_LabelValue/_Layer/_Color`` (the target-side structures in a second layer);
- ``names.yaml``: label value -> obstacle name for the NIfTI file, 2 mm margins on both carotids;
- ``margins.yaml``: the same margins for the Slicer file, keyed by segment name;
- ``robot.yaml``: the researcher's own robot (the nominal tubes with slower joints and actuator units).

The template is scenes/skullbase.yaml itself (robot, base pose, target, start; anatomy LSP).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import nibabel as nib
import nrrd
import numpy as np
import trimesh
from scipy import ndimage
from scipy.spatial.transform import Rotation

from ctrplan.scene.loader import load_scene
from ctrplan.scene.orientation import code_matrix

ROOT = Path(__file__).resolve().parents[1]
SPACING = np.array([0.4, 0.4, 1.2])  # mm along i, j, k (k: slices, along superior)
ROTATION = Rotation.from_euler("x", 10.0, degrees=True).as_matrix()  # the grid, turned 10 degrees
CROP_LSP = np.array([[-20.0, -12.0, -4.0], [20.0, 48.0, 90.0]])  # the airway's anatomy, scene frame
LPS = np.diag([-1.0, -1.0, 1.0])
SECOND_LAYER = ("sella_turcica", "right_internal_carotid", "left_internal_carotid", "optic_chiasm")
ROBOT = """# The researcher's own robot: the paper's tubes, driven slower, with actuator units.
name: my_ctr
{tubes}
limits: {{speed_mm_per_s: 5.0, speed_rad_per_s: 0.5, acceleration_mm_per_s2: 20.0,
          acceleration_rad_per_s2: 2.0}}
actuators:
  beta1: {{counts_per_mm: 2000, offset: 200000, sign: -1, name: stage_inner}}
  beta2: {{counts_per_mm: 2000, offset: 200000, sign: -1, name: stage_middle}}
  beta3: {{counts_per_mm: 2000, offset: 200000, sign: -1, name: stage_outer}}
  alpha1: {{counts_per_rad: 651.9}}
  alpha2: {{counts_per_rad: 651.9}}
  alpha3: {{counts_per_rad: 651.9}}
"""


def grid() -> tuple[np.ndarray, tuple[int, int, int]]:
    """The affine (RAS) and shape of a turned grid covering the crop."""
    to_ras = code_matrix("LSP", "RAS")
    corners = np.array([[x, y, z] for x in CROP_LSP[:, 0] for y in CROP_LSP[:, 1] for z in CROP_LSP[:, 2]])
    local = corners @ to_ras.T @ ROTATION  # coordinates along the grid's axes
    lo, hi = local.min(axis=0), local.max(axis=0)
    shape = tuple(int(v) for v in np.ceil((hi - lo) / SPACING) + 1)
    affine = np.eye(4)
    affine[:3, :3] = ROTATION * SPACING
    affine[:3, 3] = ROTATION @ lo + np.array([0.3, -0.2, 0.5])  # and offset from any round number
    return affine, shape


def surface_points(mesh: trimesh.Trimesh, spacing: float = 0.15) -> np.ndarray:
    """Points (P, 3) on the triangles of ``mesh`` at most ``spacing`` apart (a barycentric grid per
    triangle)."""
    out = []
    for tri in mesh.triangles:
        n = max(1, int(np.ceil(np.linalg.norm(tri - np.roll(tri, 1, axis=0), axis=1).max() / spacing)))
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        u, v = i[keep] / n, j[keep] / n
        out.append(tri[0] + u[:, None] * (tri[1] - tri[0]) + v[:, None] * (tri[2] - tri[0]))
    return np.concatenate(out)


def rasterise(mesh: trimesh.Trimesh, affine: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """The voxels (shape) bool a segmentation of the surface ``mesh`` (RAS mm) would hold: those
    its densely sampled surface passes through, grown by one voxel (6-connected)."""
    ijk = np.rint((surface_points(mesh) - affine[:3, 3]) @ np.linalg.inv(affine[:3, :3]).T).astype(int)
    inside = np.all((ijk >= 0) & (ijk < np.array(shape)), axis=1)
    mask = np.zeros(shape, dtype=bool)
    mask[tuple(ijk[inside].T)] = True
    return ndimage.binary_dilation(mask, structure=ndimage.generate_binary_structure(3, 1))


def cropped(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The triangles of ``mesh`` (scene frame) that reach into the crop box (the face plate is far
    larger than the airway)."""
    tri = mesh.triangles
    keep = np.all(tri.max(axis=1) >= CROP_LSP[0], axis=1) & np.all(tri.min(axis=1) <= CROP_LSP[1], axis=1)
    return trimesh.Trimesh(mesh.vertices, mesh.faces[keep], process=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    out = parser.parse_args().out
    out.mkdir(parents=True, exist_ok=True)
    scene = load_scene(ROOT / "scenes" / "skullbase.yaml")
    affine, shape = grid()
    to_ras = code_matrix("LSP", "RAS")
    labels = np.zeros(shape, dtype=np.uint8)
    layers = np.zeros((2, *shape), dtype=np.uint8)
    header = {"space": "left-posterior-superior", "kinds": ["list", "domain", "domain", "domain"]}
    rng = np.random.default_rng(0)
    for value, obstacle in enumerate(scene.obstacles, start=1):
        mesh = cropped(obstacle.to_trimesh())
        mesh = trimesh.Trimesh(mesh.vertices @ to_ras.T, mesh.faces)
        mask = rasterise(mesh, affine, shape)
        labels[mask] = value
        layer = int(obstacle.name in SECOND_LAYER)
        layers[layer][mask] = value
        n = value - 1
        header |= {f"Segment{n}_Name": obstacle.name, f"Segment{n}_LabelValue": str(value),
                   f"Segment{n}_Layer": str(layer), f"Segment{n}_ID": f"Segment_{value}",
                   f"Segment{n}_Color": " ".join(f"{c:.3f}" for c in rng.uniform(0.3, 1.0, 3))}
        print(f"{value:2d} {obstacle.name}: {int(mask.sum()):,} voxels")
    image = nib.Nifti1Image(labels, affine)
    image.header.set_xyzt_units("mm")
    nib.save(image, out / "labels.nii.gz")
    header["space directions"] = np.vstack([np.full(3, np.nan), (LPS @ affine[:3, :3]).T])
    header["space origin"] = LPS @ affine[:3, 3]
    nrrd.write(str(out / "labels.seg.nrrd"), layers, header)
    margin = {"right_internal_carotid", "left_internal_carotid"}
    (out / "names.yaml").write_text("".join(
        f"{v}: {{name: {o.name}, margin_mm: 2.0}}\n" if o.name in margin else f"{v}: {o.name}\n"
        for v, o in enumerate(scene.obstacles, start=1)))
    (out / "margins.yaml").write_text("".join(f"{name}: {{margin_mm: 2.0}}\n" for name in sorted(margin)))
    nominal = (ROOT / "ctrplan" / "data" / "nominal.yaml").read_text()
    tubes = nominal[nominal.index("tubes:"):nominal.index("# Snap-free")].rstrip()
    (out / "robot.yaml").write_text(ROBOT.format(tubes=tubes))
    print(f"{shape[0]}x{shape[1]}x{shape[2]} voxels of {SPACING.tolist()} mm -> {out}")


if __name__ == "__main__":
    main()
