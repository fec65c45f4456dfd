"""Your own patient, without silent traps (issue 41, frames): a small endonasal phantom drawn here in
RAS world mm -- a face plate, both internal carotid arteries, a sella -- saved on a turned, offset,
anisotropic grid as NIfTI (RAS by definition) and as a 3D Slicer ``.seg.nrrd`` (LPS, named, coloured
segments, one in a second layer). Both must give the same scene to within a voxel, with the right
carotid on the right; a volume whose frame is lost or wrong must be refused or named as mirrored;
unnamed labels are an error or a listed warning; a mesh in metres is flagged on its own."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import nrrd
import numpy as np
import pytest
import trimesh
import yaml
from scipy.spatial.transform import Rotation

from ctrplan.base.errors import InputError
from ctrplan.cli.app import main
from ctrplan.planning.scene_check import check_scene
from ctrplan.scene.labels import scene_from_labels
from ctrplan.scene.loader import load_scene
from ctrplan.scene.orientation import code_matrix, declared_space
from ctrplan.scene.segmentation import MAX_FACES, label_mesh, read_label_volume
from tests.model.test_scene_labels import save_nifti

SPACING = np.array([0.8, 0.8, 1.2])  # mm along i, j, k
ROTATION = Rotation.from_euler("z", 10.0, degrees=True).as_matrix()
SHAPE = (64, 84, 32)
ORIGIN = np.array([-22.0, -20.0, -18.0])  # RAS mm of voxel (0, 0, 0)
LPS = np.diag([-1.0, -1.0, 1.0])
#: label value, Slicer segment name, colour, layer
SEGMENTS = ((1, "face", (0.9, 0.7, 0.6), 0), (2, "right_internal_carotid", (0.8, 0.1, 0.1), 0),
            (3, "left_internal_carotid", (0.8, 0.1, 0.1), 0), (1, "sella", (0.5, 0.5, 0.9), 1),
            (4, "anterior_clinoid", (0.9, 0.9, 0.8), 0), (5, "posterior_clinoid", (0.9, 0.9, 0.8), 0))
STRUCTURES = ("face", "right_internal_carotid", "left_internal_carotid", "sella", "anterior_clinoid",
              "posterior_clinoid")
NAMES = ("1: face\n2: right_internal_carotid\n3: {name: left_internal_carotid, margin_mm: 2.0}\n4: sella\n"
         "5: anterior_clinoid\n6: posterior_clinoid\n")


def affine_ras() -> np.ndarray:
    A = np.eye(4)
    A[:3, :3] = ROTATION * SPACING
    A[:3, 3] = ORIGIN
    return A


def anatomy_masks() -> dict[str, np.ndarray]:
    """The structures judged at every voxel centre (RAS mm): name -> (SHAPE) bool."""
    ijk = np.stack(np.meshgrid(*(np.arange(n) for n in SHAPE), indexing="ij"), axis=-1).reshape(-1, 3)
    x, y, z = (ijk @ affine_ras()[:3, :3].T + ORIGIN).T
    masks = {
        "face": (np.abs(x) <= 14) & (y >= 38) & (y <= 44) & (np.abs(z) <= 10),
        "right_internal_carotid": ((x - 8) ** 2 + y**2 <= 2.5**2) & (np.abs(z) <= 9),
        "left_internal_carotid": ((x + 8) ** 2 + y**2 <= 2.5**2) & (np.abs(z) <= 9),
        "sella": x**2 + (y + 5) ** 2 + (z - 4) ** 2 <= 4.0**2,
        "anterior_clinoid": x**2 + (y - 3) ** 2 + (z - 11) ** 2 <= 1.6**2,
        "posterior_clinoid": x**2 + (y + 11) ** 2 + (z - 11) ** 2 <= 1.6**2,
    }
    return {k: v.reshape(SHAPE) for k, v in masks.items()}


def nifti_labels() -> np.ndarray:
    labels = np.zeros(SHAPE, dtype=np.int16)
    for value, name in enumerate(STRUCTURES, 1):
        labels[anatomy_masks()[name]] = value
    return labels


def write_seg_nrrd(path: Path, space: str = "left-posterior-superior", frame: np.ndarray = LPS) -> None:
    """As 3D Slicer writes a segmentation: two layers (the sella overlaps nothing here but sits in
    its own layer, as overlapping segments do), directions and origin in ``frame`` (LPS)."""
    masks = anatomy_masks()
    layers = np.zeros((2, *SHAPE), dtype=np.uint8)
    header = {"space": space, "kinds": ["list", "domain", "domain", "domain"]}
    for n, (value, name, color, layer) in enumerate(SEGMENTS):
        layers[layer][masks[name]] = value
        header |= {f"Segment{n}_Name": name, f"Segment{n}_LabelValue": str(value),
                   f"Segment{n}_Layer": str(layer), f"Segment{n}_Color": " ".join(map(str, color)),
                   f"Segment{n}_ID": f"Segment_{n + 1}"}
    A = affine_ras()
    header["space directions"] = np.vstack([np.full(3, np.nan), (frame @ A[:3, :3]).T])
    header["space origin"] = frame @ A[:3, 3]
    nrrd.write(str(path), layers, header)


def template(folder: Path, anatomy: str = "") -> Path:
    path = folder / f"template{len(anatomy)}.yaml"
    path.write_text(
        "robot: nominal\nbase_pose:\n  position: [0.0, 200.0, 0.0]\n  rotation: {z_axis: [0, -1, 0]}\n"
        "target:\n  point: [0.0, -5.0, 4.0]\n  tolerance_mm: 2.0\n"
        "start: [-80.0, -65.0, -10.0, 0.0, 0.0, 0.0]\n"
        + anatomy)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("patient")
    save_nifti(folder / "labels.nii.gz", nifti_labels(), affine_ras())
    write_seg_nrrd(folder / "labels.seg.nrrd")
    (folder / "names.yaml").write_text(NAMES)
    return {"folder": folder, "nifti": folder / "labels.nii.gz", "seg": folder / "labels.seg.nrrd",
            "names": folder / "names.yaml", "template": template(folder)}


@pytest.fixture(scope="module")
def made(files) -> dict[str, Path]:
    out = {}
    for kind in ("nifti", "seg"):
        out[kind] = files["folder"] / kind / "scene.yaml"
        names = ["--names", str(files["names"])] if kind == "nifti" else []
        assert main(["scene", "from-labels", str(files[kind]), *names, "--template", str(files["template"]),
                     "--out", str(out[kind])]) == 0
    return out


def test_slicer_segments_are_read_with_names_values_colours_and_layers(files):
    volume = read_label_volume(files["seg"])
    assert volume.space == "LPS" and volume.labels.shape == (2, *SHAPE)
    assert [(s.value, s.name, s.layer) for s in volume.segments] == [(v, n, la) for v, n, _, la in SEGMENTS]
    assert volume.segments[1].color == (0.8, 0.1, 0.1)
    np.testing.assert_allclose(volume.affine, affine_ras(), atol=1e-9)  # LPS converted to RAS


def test_nifti_and_seg_nrrd_of_one_anatomy_give_one_scene_within_a_voxel(made):
    a, b = load_scene(made["nifti"]), load_scene(made["seg"])
    assert sorted(o.name for o in a.obstacles) == sorted(o.name for o in b.obstacles)
    voxel = float(SPACING.max())
    for oa in a.obstacles:
        ob = next(o for o in b.obstacles if o.name == oa.name)
        np.testing.assert_allclose(oa.bounds, ob.bounds, atol=voxel)
        gap = trimesh.proximity.ProximityQuery(ob.to_trimesh()).signed_distance(oa.vertices[::7])
        assert np.abs(gap).max() <= voxel, oa.name
    right = next(o for o in a.obstacles if o.name == "right_internal_carotid").bounds
    assert right[0, 0] > 4.5 and right[1, 0] < 11.5  # RAS: the right carotid at x = +8 mm
    assert a.anatomy == {"x": "right", "y": "anterior", "z": "superior"}  # the frame, written down
    assert declared_space(next(iter((made["seg"].parent / "scene_meshes").glob("*.stl")))) == "RAS"
    assert [o.margin_mm for o in a.obstacles if o.name == "left_internal_carotid"] == [2.0]


def test_meshes_go_into_the_templates_anatomy_frame(files, made, tmp_path):
    lsp = template(files["folder"], "anatomy: {x: left, y: superior, z: posterior}\n")
    out = tmp_path / "lsp.yaml"
    made_lsp = scene_from_labels(files["seg"], None, lsp, out)
    assert made_lsp.frame == "LSP"
    ras = load_scene(made["seg"])
    M = code_matrix("RAS", "LSP")  # closed form: x = -x_R, y = z_S, z = -y_A
    np.testing.assert_array_equal(M, [[-1, 0, 0], [0, 0, 1], [0, -1, 0]])
    for o in load_scene(out).obstacles:
        r = next(p for p in ras.obstacles if p.name == o.name)
        mapped = r.vertices @ M.T
        np.testing.assert_allclose(o.vertices[np.lexsort(o.vertices.T)], mapped[np.lexsort(mapped.T)],
                                   atol=1e-4)
        assert o.to_trimesh().volume > 0  # still outward


@pytest.mark.parametrize("case", ["half_turn", "mirror"])
def test_a_mirrored_or_turned_import_is_named(files, tmp_path, capsys, case):
    """LPS directions declared as RAS (what the issue saw: a half turn about superior), and a file
    whose x axis is flipped (a mirror image): scene check names it, exit 2."""
    path = tmp_path / "wrong.seg.nrrd"
    if case == "half_turn":
        write_seg_nrrd(path, space="right-anterior-superior")
        expect = "turned half a turn about the superior-inferior axis"
    else:
        write_seg_nrrd(path, space="right-anterior-superior", frame=np.diag([-1.0, 1.0, 1.0]))
        expect = "the anatomy is mirrored right-left: right_internal"
    out = tmp_path / "wrong.yaml"
    scene = scene_from_labels(path, None, files["template"], out).scene
    report = check_scene(scene, reach=False)
    problems = [p.message for p in report.problems if p.kind == "orientation"]
    assert len(problems) == 1 and expect in problems[0], problems
    assert "right_internal_carotid lies 16" in problems[0] and "left of left_internal_carotid" in problems[0]


def test_the_right_scene_passes_the_orientation_check(made):
    report = check_scene(load_scene(made["seg"], check_start=False), reach=False)
    assert not [p for p in report.problems if p.kind == "orientation"]
    assert "2 pair(s) of sided structures on their sides" in report.facts["orientation"]


@pytest.mark.parametrize("space", ["scanner-xyz", None])
def test_a_volume_whose_space_is_unknown_is_refused(files, tmp_path, capsys, space):
    path = tmp_path / "unknown.nrrd"
    A = affine_ras()
    header = {"space directions": A[:3, :3].T, "space origin": A[:3, 3]}
    if space is None:
        header["space dimension"] = 3
    else:
        header["space"] = space
    nrrd.write(str(path), nifti_labels(), header)
    capsys.readouterr()
    assert main(["scene", "from-labels", str(path), "--names", str(files["names"]), "--template",
                 str(files["template"]), "--out", str(tmp_path / "x" / "new.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ("names no patient directions" if space else "has no 'space' field") in err[0]
    assert not (tmp_path / "x").exists()


def test_a_label_the_names_file_misses_is_an_error_listing_it_or_a_warning(files, tmp_path, capsys):
    names = tmp_path / "names.yaml"
    names.write_text(NAMES.replace("2: right_internal_carotid\n", ""))  # forgets the right carotid
    args = ["scene", "from-labels", str(files["nifti"]), "--names", str(names), "--template",
            str(files["template"]), "--out", str(tmp_path / "new.yaml")]
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "1 label(s) present" in err[0] and "label 2" in err[0], err
    assert not (tmp_path / "new.yaml").exists()
    assert main([*args, "--unnamed", "skip"]) == 0
    err = capsys.readouterr().err
    assert "ctrplan: warning: 1 label(s)" in err and "label 2" in err and "left out" in err
    assert [o.name for o in load_scene(tmp_path / "new.yaml").obstacles] == \
        [n for n in STRUCTURES if n != "right_internal_carotid"]


def test_names_file_renames_slicer_segments_by_name(files, tmp_path):
    names = tmp_path / "names.yaml"
    names.write_text("right_internal_carotid: {name: ica_r, margin_mm: 2.0}\nsella: {margin_mm: 0.5}\n")
    made = scene_from_labels(files["seg"], names, files["template"], tmp_path / "s.yaml")
    got = {o.name: o.margin_mm for o in made.scene.obstacles}
    assert got == {"face": 0.0, "ica_r": 2.0, "left_internal_carotid": 0.0, "sella": 0.5,
                   "anterior_clinoid": 0.0, "posterior_clinoid": 0.0}
    names.write_text("1: face\n")  # label 1 is in both layers: ambiguous
    with pytest.raises(InputError, match="label 1 is in layers 0, 1"):
        scene_from_labels(files["seg"], names, files["template"], tmp_path / "s2.yaml")
    names.write_text("Right ICA: carotid\n")
    with pytest.raises(InputError, match="names.yaml:1: Right ICA: .* has no segment of that name"):
        scene_from_labels(files["seg"], names, files["template"], tmp_path / "s3.yaml")


def scaled_copy(scene_file: Path, out: Path, scales: dict[str, float]) -> Path:
    """The scene with absolute mesh paths and ``scale:`` per obstacle name."""
    data = yaml.safe_load(scene_file.read_text())
    for o in data["obstacles"]:
        o["mesh"] = str(scene_file.parent / o["mesh"])
        if o["name"] in scales:
            o["scale"] = scales[o["name"]]
    out.write_text(yaml.safe_dump(data))
    return out


def test_a_mesh_in_metres_among_millimetres_is_flagged_on_its_own(made, tmp_path):
    one = scaled_copy(made["nifti"], tmp_path / "one.yaml", {"sella": 0.001})
    report = check_scene(load_scene(one, check_start=False))
    scale = [p.message for p in report.problems if p.kind == "scale"]
    assert len(scale) == 1 and "(sella)" in scale[0] and "a mesh in metres?" in scale[0], scale
    assert report.facts["other checks"] == "skipped until the scale is fixed"
    every = scaled_copy(made["nifti"], tmp_path / "every.yaml", dict.fromkeys(STRUCTURES, 0.001))
    report = check_scene(load_scene(every, check_start=False))
    assert len([p for p in report.problems if p.kind == "scale"]) == len(STRUCTURES)


def test_a_small_structure_drawn_in_millimetres_is_not_called_metres(made):
    """A 3 mm structure far from the origin is small, not in metres."""
    scene = load_scene(made["nifti"], check_start=False)
    from dataclasses import replace

    from ctrplan.scene.objects import Obstacle

    tiny = Obstacle("tiny_nodule", "sphere", pose=np.array([[1, 0, 0, 0], [0, 1, 0, 30.0], [0, 0, 1, 2.0],
                                                            [0, 0, 0, 1]]), radius=1.0)
    report = check_scene(replace(scene, obstacles=(*scene.obstacles, tiny)), reach=False)
    assert not [p for p in report.problems if p.kind == "scale"]


def test_large_surfaces_are_decimated_and_stay_within_a_voxel():
    """Decimation does what the docs say: above MAX_FACES triangles, down to it, closed and
    outward, within one voxel of the shape."""
    from ctrplan.scene.segmentation import LabelVolume

    n, h, r = 96, 0.5, 20.0
    ijk = np.stack(np.meshgrid(*(np.arange(n),) * 3, indexing="ij"), axis=-1)
    world = ijk * h
    centre = np.full(3, (n - 1) * h / 2)
    labels = (np.linalg.norm(world - centre, axis=-1) <= r).astype(np.int64)
    mesh = label_mesh(LabelVolume(labels, np.diag([h, h, h, 1.0]), "sphere"), 1)
    assert len(mesh.faces) <= MAX_FACES and mesh.is_watertight and mesh.is_volume
    gap = np.abs(np.linalg.norm(mesh.vertices - centre, axis=1) - r)
    assert gap.max() <= h
    assert mesh.volume == pytest.approx(4 / 3 * math.pi * r**3, rel=0.03)


def test_a_slicer_mesh_in_lps_is_converted_to_the_scenes_frame(made, tmp_path):
    """A mesh file that declares SPACE=LPS (3D Slicer's export) lands where its RAS twin does."""
    scene = load_scene(made["seg"])
    carotid = next(o for o in scene.obstacles if o.name == "right_internal_carotid")
    lps = trimesh.Trimesh(carotid.vertices @ LPS.T, carotid.faces[:, ::-1])
    (tmp_path / "ica.stl").write_bytes(b"SPACE=LPS".ljust(80, b" ") + lps.export(file_type="stl")[80:])
    text = made["seg"].read_text().replace("mesh: scene_meshes/right_internal_carotid.stl",
                                           f"mesh: {tmp_path}/ica.stl")
    (tmp_path / "s.yaml").write_text(text.replace("scene_meshes/", f"{made['seg'].parent}/scene_meshes/"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = load_scene(tmp_path / "s.yaml")
    moved = next(o for o in again.obstacles if o.name == "right_internal_carotid")
    assert moved.space == "LPS"
    np.testing.assert_allclose(moved.bounds, carotid.bounds, atol=1e-3)
