"""`ctrplan scene from-labels`: label volumes drawn from analytic shapes, placed by a non-trivial
affine (anisotropic voxels, an offset, an oblique rotation), must become watertight meshes that lie
within one voxel of the shapes' true surfaces in world millimetres. The shapes are defined in the
world frame and rasterised here by mapping every voxel centre through the affine, so a transposed
rotation, a swapped spacing or a lost origin in the reader puts the mesh far from the surface."""

from __future__ import annotations

import math
from pathlib import Path

import nibabel as nib
import nrrd
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from ctrplan.cli.app import main
from ctrplan.scene.loader import load_scene
from tests.paths import REPO

SPACING = np.array([0.6, 0.9, 1.3])  # mm along i, j, k
ROTATION = Rotation.from_rotvec(np.deg2rad(35.0) * np.array([1.0, 2.0, 0.5]) / math.sqrt(5.25)).as_matrix()
ORIGIN = np.array([-30.0, 20.0, 95.0])  # mm, world position of voxel (0, 0, 0)
SHAPE = (70, 50, 40)

SPHERE = (np.array([-8.0, 30.0, 120.0]), 6.0)  # centre (world mm), radius
CAPSULE = (np.array([-18.0, 34.0, 108.0]), np.array([-6.0, 44.0, 118.0]), 3.0)  # segment ends, radius


def affine() -> np.ndarray:
    A = np.eye(4)
    A[:3, :3] = ROTATION * SPACING  # column c: the world step of one voxel along axis c
    A[:3, 3] = ORIGIN
    return A


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    t = np.clip((p - a) @ d / (d @ d), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * d), axis=1)


def sphere_gap(p: np.ndarray) -> np.ndarray:
    """Distance (mm) of world points (n, 3) from the sphere's surface."""
    c, r = SPHERE
    return np.abs(np.linalg.norm(p - c, axis=1) - r)


def capsule_gap(p: np.ndarray) -> np.ndarray:
    a, b, r = CAPSULE
    return np.abs(segment_distance(p, a, b) - r)


def label_volume() -> np.ndarray:
    """Labels (SHAPE): 3 inside the sphere, 5 inside the capsule, judged at each voxel centre."""
    ijk = np.stack(np.meshgrid(*(np.arange(n) for n in SHAPE), indexing="ij"), axis=-1).reshape(-1, 3)
    world = ijk @ affine()[:3, :3].T + ORIGIN
    labels = np.zeros(len(world), dtype=np.int16)
    c, r = SPHERE
    labels[np.linalg.norm(world - c, axis=1) <= r] = 3
    a, b, rc = CAPSULE
    labels[segment_distance(world, a, b) <= rc] = 5
    return labels.reshape(SHAPE)


def save_nifti(path: Path, labels: np.ndarray, affine: np.ndarray) -> None:
    """A label map as a segmentation tool saves it: NIfTI, world RAS mm."""
    image = nib.Nifti1Image(labels, affine)
    image.header.set_xyzt_units("mm")
    nib.save(image, path)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("labels")
    save_nifti(folder / "labels.nii.gz", label_volume(), affine())
    (folder / "names.yaml").write_text("3: pituitary_phantom\n5: {name: carotid_phantom, margin_mm: 1.5}\n")
    template = folder / "template.yaml"
    template.write_text(
        "name: phantom\nrobot: nominal\nbase_pose:\n  position: [-10.0, 30.0, 0.0]\n"
        "obstacles:\n- {name: old_ball, sphere: {center: [0.0, 0.0, 300.0], radius: 1.0}}\n"
        "target:\n  point: [-10.0, 30.0, 180.0]\n  tolerance_mm: 2.0\n"
        "start: [-80.0, -65.0, -10.0, 0.0, 0.0, 0.0]\nplanner:\n  time_limit_s: 5.0\n")
    return {"folder": folder, "labels": folder / "labels.nii.gz", "names": folder / "names.yaml",
            "template": template}


def run(inputs: dict, labels: Path, out: Path, names: Path | None = None) -> int:
    return main(["scene", "from-labels", str(labels), "--names", str(names or inputs["names"]),
                 "--template", str(inputs["template"]), "--out", str(out)])


@pytest.fixture(scope="module")
def made(inputs) -> Path:
    out = inputs["folder"] / "made" / "phantom.yaml"
    assert run(inputs, inputs["labels"], out) == 0
    return out


def test_each_label_becomes_a_watertight_mesh_within_one_voxel_of_its_shape(made):
    scene = load_scene(made)
    assert [o.name for o in scene.obstacles] == ["pituitary_phantom", "carotid_phantom"]
    voxel = float(SPACING.max())
    for obstacle, gap, volume in ((scene.obstacles[0], sphere_gap, 4 / 3 * math.pi * SPHERE[1] ** 3),
                                  (scene.obstacles[1], capsule_gap,
                                   math.pi * CAPSULE[2] ** 2 * (np.linalg.norm(CAPSULE[1] - CAPSULE[0])
                                                                + 4 / 3 * CAPSULE[2]))):
        mesh = trimesh.Trimesh(obstacle.vertices, obstacle.faces)
        assert mesh.is_watertight and mesh.is_volume, obstacle.name
        assert mesh.volume > 0  # outward normals
        assert gap(np.asarray(mesh.vertices)).max() <= voxel, obstacle.name
        assert mesh.volume == pytest.approx(volume, rel=0.05), obstacle.name


def test_the_template_is_kept_but_its_obstacles(made, inputs):
    new, old = load_scene(made), load_scene(inputs["template"])
    assert new.robot.fingerprint == old.robot.fingerprint
    np.testing.assert_array_equal(new.base_pose, old.base_pose)
    np.testing.assert_array_equal(new.start, old.start)
    np.testing.assert_array_equal(new.target.center, old.target.center)
    assert new.settings == old.settings
    assert all((made.parent / "phantom_meshes" / f"{o.name}.stl").is_file() for o in new.obstacles)
    assert [o.margin_mm for o in new.obstacles] == [0.0, 1.5]  # NAMES.yaml's margin_mm is kept


def test_a_robot_file_of_the_template_is_found_from_the_new_scene(inputs, tmp_path):
    nominal = REPO / "ctrplan" / "data" / "nominal.yaml"
    robots = inputs["folder"].parent / "robots"
    robots.mkdir(exist_ok=True)
    (robots / "mine.yaml").write_text(nominal.read_text().replace("name: nominal", "name: mine"))
    template = inputs["folder"] / "template_robot.yaml"
    text = inputs["template"].read_text()
    template.write_text(text.replace("robot: nominal", "robot: ../robots/mine.yaml"))
    out = tmp_path / "deeper" / "new.yaml"
    assert main(["scene", "from-labels", str(inputs["labels"]), "--names", str(inputs["names"]),
                 "--template", str(template), "--out", str(out)]) == 0
    assert load_scene(out).robot.name == "mine"


def test_an_nrrd_volume_is_placed_by_its_space_directions(inputs, tmp_path):
    A = affine()
    path = tmp_path / "labels.nrrd"
    nrrd.write(str(path), label_volume(), {"space": "right-anterior-superior",
                                           "space directions": A[:3, :3].T, "space origin": A[:3, 3]})
    out = tmp_path / "from_nrrd.yaml"
    assert run(inputs, path, out) == 0
    sphere = load_scene(out).obstacles[0]
    assert sphere_gap(sphere.vertices).max() <= SPACING.max()


def test_a_transposed_rotation_would_miss_the_shape(inputs):
    """The check above can fail: the same voxels placed with the rotation transposed lie far off."""
    from ctrplan.scene.segmentation import LabelVolume, label_mesh

    A = affine()
    A[:3, :3] = ROTATION.T * SPACING
    mesh = label_mesh(LabelVolume(labels=label_volume().astype(np.int64), affine=A, source="x"), 3)
    assert sphere_gap(np.asarray(mesh.vertices)).max() > 3 * SPACING.max()


@pytest.mark.parametrize("case", ["missing_label", "no_affine", "missing_file", "bad_names", "bad_margin"])
def test_bad_input_is_one_line_and_writes_nothing(inputs, tmp_path, capsys, case):
    labels, names = inputs["labels"], inputs["names"]
    if case == "missing_label":
        names = tmp_path / "names.yaml"
        names.write_text("3: pituitary_phantom\n9: absent\n")
        expect = "label 9 has no voxel"
    elif case == "no_affine":
        image = nib.Nifti1Image(label_volume(), affine())
        image.set_sform(None, code=0)
        image.set_qform(None, code=0)
        labels = tmp_path / "no_affine.nii"
        nib.save(image, labels)
        expect = "no affine"
    elif case == "missing_file":
        labels = tmp_path / "nothing.nii.gz"
        expect = "file not found"
    elif case == "bad_names":
        names = tmp_path / "names.yaml"
        names.write_text("0: carotid\n")
        expect = "positive integer label"
    else:
        names = tmp_path / "names.yaml"
        names.write_text("3: {name: carotid, margin_mm: -1}\n")
        expect = "3.margin_mm: expected a finite number >= 0 (mm)"
    out = tmp_path / "sub" / "new.yaml"
    capsys.readouterr()
    assert run(inputs, labels, out, names) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expect in err[0], err
    assert not (tmp_path / "sub").exists()


def test_the_shipped_example_is_what_from_labels_makes_of_its_volume(tmp_path):
    """examples/segmentation (scripts/label_example.py): the committed scene is reproduced from the
    committed volume, names and template."""
    folder = REPO / "examples" / "segmentation"
    out = tmp_path / "phantom.yaml"
    assert main(["scene", "from-labels", str(folder / "phantom.nii.gz"), "--names",
                 str(folder / "names.yaml"), "--template", str(folder / "template.yaml"), "--out",
                 str(out)]) == 0
    made, shipped = load_scene(out), load_scene(folder / "phantom.yaml")
    assert [o.name for o in made.obstacles] == [o.name for o in shipped.obstacles] == \
        ["target_organ", "artery", "nerve"]
    for a, b in zip(made.obstacles, shipped.obstacles, strict=True):
        np.testing.assert_allclose(a.bounds, b.bounds, atol=1e-4)
