"""Anatomy from a segmentation: label volumes (NIfTI, NRRD, 3D Slicer ``.seg.nrrd``) to watertight
meshes in world millimetres, **world = RAS+** (x right, y anterior, z superior) for every file.

A label volume is an integer array on a voxel grid plus the affine that maps a voxel index
``(i, j, k, 1)`` to world coordinates in mm (voxel spacing, orientation and origin). NIfTI files
are read with nibabel (world = RAS+ by the format's definition: the volume's sform, else its qform;
a file with neither has no known placement and is refused); NRRD files with pynrrd (``space
directions`` and ``space origin`` in the file's ``space``: ``left-posterior-superior`` (LPS, what
DICOM and 3D Slicer write), ``right-anterior-superior``, ``left-anterior-superior`` or their
three-letter forms are converted to RAS; a file without a ``space``, or with a space that names no
patient directions (``scanner-xyz``, ``3D-right-handed`` ...), is refused: its mirror image would
load as silently as itself). A 3D Slicer segmentation (``.seg.nrrd``) also names its segments:
``Segment<N>_Name``, ``_LabelValue``, ``_Layer`` and ``_Color`` are read into `Segment` records
(overlapping segments lie in separate layers: a 4-D file with a ``list`` axis).

Each named label becomes one mesh: marching cubes on the label's voxels (the volume padded by one
empty voxel, so every surface closes), outward normals, light Humphrey-class Laplacian smoothing (it
removes the voxel staircase and, unlike plain Laplacian or trimesh's Taubin filter, keeps the
enclosed volume: within 2 % on the test shapes) and quadric decimation to `MAX_FACES` triangles
for larger surfaces, kept only if the result is still a closed, outward volume. The surface lies
within one voxel of the segmentation's boundary (the half-voxel iso-surface, moved by smoothing by
a fraction of a voxel).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ctrplan.base.errors import InputError
from ctrplan.scene.orientation import RAS, code_matrix, parse_space

#: Length units a NIfTI header may declare, as millimetres per unit ("unknown" is read as mm).
_NIFTI_MM_PER_UNIT = {"mm": 1.0, "meter": 1000.0, "micron": 1e-3, "unknown": 1.0}
#: Marching-cubes surfaces with more faces than this are decimated (quadric) to it.
MAX_FACES = 20_000
#: Humphrey smoothing passes.
SMOOTHING_ITERATIONS = 10
_SEGMENT_KEY = re.compile(r"^Segment(\d+)_(\w+)$")


@dataclass(frozen=True)
class Segment:
    """A labelled structure of a volume: voxels equal to ``value`` in layer ``layer``; ``name`` and
    ``color`` (r, g, b in 0..1) as a segmentation file gives them (None for a plain label map)."""

    value: int
    layer: int = 0
    name: str | None = None
    color: tuple[float, float, float] | None = None

    def describe(self, layers: int = 1) -> str:
        where = f"label {self.value}" + (f" of layer {self.layer}" if layers > 1 else "")
        return f"{where} ({self.name!r})" if self.name else where


@dataclass(frozen=True)
class LabelVolume:
    """Integer labels on a voxel grid: ``labels`` (L, I, J, K), L layers of one grid (a plain label
    map has one; a 3-D array is taken as one layer); ``affine`` (4, 4) maps a voxel index to world mm
    (RAS+); ``space``: the patient directions the file was written in (e.g. ``"LPS"``, converted);
    ``segments``: the structures the file names (empty for a plain label map)."""

    labels: np.ndarray
    affine: np.ndarray
    source: str
    space: str = RAS
    segments: tuple[Segment, ...] = ()

    def __post_init__(self) -> None:
        if self.labels.ndim == 3:
            object.__setattr__(self, "labels", self.labels[None])

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        return tuple(self.labels.shape[1:])

    @property
    def spacing_mm(self) -> np.ndarray:
        """Voxel edge lengths (3,) mm along i, j, k."""
        return np.linalg.norm(self.affine[:3, :3], axis=0)

    def to_world(self, ijk: np.ndarray) -> np.ndarray:
        """World positions (..., 3) mm (RAS+) of (fractional) voxel indices ``ijk`` (..., 3)."""
        return ijk @ self.affine[:3, :3].T + self.affine[:3, 3]

    def present(self) -> tuple[Segment, ...]:
        """Every (layer, value) with voxels, value > 0, as `Segment` records (the file's name and
        colour where it gives them), in layer then value order."""
        named = {(s.layer, s.value): s for s in self.segments}
        return tuple(named.get((layer, int(v)), Segment(int(v), layer))
                     for layer in range(self.labels.shape[0])
                     for v in np.unique(self.labels[layer]) if v > 0)

    def mask(self, segment: Segment) -> np.ndarray:
        """The voxels (I, J, K) bool of ``segment``."""
        return self.labels[segment.layer] == segment.value


def read_label_volume(path: str | Path) -> LabelVolume:
    """Read a label volume (``.nii``, ``.nii.gz``, ``.nrrd``, ``.seg.nrrd``, ``.nhdr``) into RAS+
    world mm; every problem is an `InputError` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    name = path.name.lower()
    space, segments = RAS, ()
    if name.endswith((".nii", ".nii.gz")):
        labels, affine = _read_nifti(path)
    elif name.endswith((".nrrd", ".nhdr")):
        labels, affine, space, segments = _read_nrrd(path)
    else:
        raise InputError(f"{path}: unsupported label volume (use .nii, .nii.gz, .nrrd, .seg.nrrd or .nhdr)")
    if labels.ndim == 4 and labels.shape[0] == 1:
        labels = labels[0]
    if labels.dtype.kind == "f":
        if not np.all(np.isfinite(labels)) or np.any(labels != np.round(labels)):
            raise InputError(f"{path}: labels must be integers (found non-integer voxel values)")
    elif labels.dtype.kind not in "iub":
        raise InputError(f"{path}: labels must be integers, got voxel type {labels.dtype}")
    if not np.all(np.isfinite(affine)) or abs(np.linalg.det(affine[:3, :3])) < 1e-12:
        raise InputError(f"{path}: the voxel-to-world affine is not invertible: {affine.tolist()}")
    volume = LabelVolume(labels=labels.astype(np.int64), affine=affine, source=str(path), space=space,
                         segments=segments)
    for s in segments:
        if s.layer >= volume.labels.shape[0]:
            raise InputError(f"{path}: segment {s.name!r} is in layer {s.layer}, but the file has "
                             f"{volume.labels.shape[0]} layer(s)")
    return volume


def _read_nifti(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import nibabel as nib

    try:
        image = nib.load(str(path))
        labels = np.squeeze(np.asanyarray(image.dataobj))
    except Exception as exc:  # nibabel raises many types on corrupt files
        raise InputError(f"{path}: cannot read NIfTI ({exc})") from None
    if labels.ndim != 3:
        raise InputError(f"{path}: expected a 3-D label volume, got shape {labels.shape}")
    header = image.header
    sform, sform_code = header.get_sform(coded=True)
    qform, qform_code = header.get_qform(coded=True)
    affine = sform if sform_code else qform if qform_code else None
    if affine is None:
        raise InputError(f"{path}: no affine (sform_code and qform_code are both 0): the voxels' place "
                         f"in the world is unknown; save the segmentation with its image's geometry")
    unit = header.get_xyzt_units()[0]
    scale = _NIFTI_MM_PER_UNIT.get(unit)
    if scale is None:
        raise InputError(f"{path}: unsupported spatial unit {unit!r} in the header")
    affine = np.array(affine, dtype=float)
    affine[:3, :] *= scale
    return labels, affine


def _read_nrrd(path: Path) -> tuple[np.ndarray, np.ndarray, str, tuple[Segment, ...]]:
    """Labels with the layer axis (if any) first, the RAS affine, the file's space, its segments."""
    import nrrd

    try:
        labels, header = nrrd.read(str(path))
    except Exception as exc:  # pynrrd raises many types on corrupt files
        raise InputError(f"{path}: cannot read NRRD ({exc})") from None
    directions = header.get("space directions")
    origin = header.get("space origin")
    if directions is None or origin is None:
        raise InputError(f"{path}: no affine (the header lacks 'space directions' or 'space origin')")
    if "space" not in header:
        raise InputError(f"{path}: the header has no 'space' field: the patient directions of its axes "
                         f"are unknown (a mirrored volume would load the same); save it with a space such "
                         f"as left-posterior-superior")
    space = parse_space(header["space"])
    if space is None:
        raise InputError(f"{path}: space {header['space']!r} names no patient directions (expected "
                         f"left-posterior-superior, right-anterior-superior, left-anterior-superior or "
                         f"LPS, RAS, LAS): refusing to guess its orientation")
    spatial = [d is not None and np.all(np.isfinite(d)) for d in directions]
    if sum(spatial) != 3 or len(spatial) != labels.ndim:
        raise InputError(f"{path}: expected 3 spatial 'space directions', got "
                         f"{[None if d is None else list(d) for d in directions]}")
    if labels.ndim == 4:  # a Slicer segmentation with layers: the non-spatial (list) axis first
        labels = np.moveaxis(labels, spatial.index(False), 0)
    to_ras = code_matrix(space, RAS)
    affine = np.eye(4)
    # NRRD lists one direction (a column of the affine) per axis
    columns = np.array([d for d, s in zip(directions, spatial, strict=True) if s], dtype=float).T
    affine[:3, :3] = to_ras @ columns
    affine[:3, 3] = to_ras @ np.asarray(origin, dtype=float)
    return labels, affine, space, _segments(path, header, labels.shape[0] if labels.ndim == 4 else 1)


def _segments(path: Path, header: dict, layers: int) -> tuple[Segment, ...]:
    """The segments a 3D Slicer ``.seg.nrrd`` header names (``Segment<N>_Name``, ``_LabelValue``,
    ``_Layer``, ``_Color``); files older than Slicer 4.11 have no label value and one layer per
    segment (value 1)."""
    fields: dict[int, dict[str, str]] = {}
    for key, value in header.items():
        match = _SEGMENT_KEY.match(str(key))
        if match:
            fields.setdefault(int(match.group(1)), {})[match.group(2)] = str(value).strip()
    segments = []
    for n, f in sorted(fields.items()):
        name = f.get("Name") or f.get("ID") or f"Segment{n}"
        where = f"{path}: Segment{n} ({name!r})"
        try:
            value = int(f.get("LabelValue", "1"))
            layer = int(f.get("Layer", str(n if layers > 1 else 0)))
            color = tuple(float(c) for c in f["Color"].split()) if "Color" in f else None
        except ValueError:
            raise InputError(f"{where}: unreadable LabelValue, Layer or Color "
                             f"({ {k: f.get(k) for k in ('LabelValue', 'Layer', 'Color')} })") from None
        if value <= 0 or layer < 0 or (color is not None and len(color) != 3):
            raise InputError(f"{where}: LabelValue must be > 0, Layer >= 0 and Color three numbers")
        segments.append(Segment(value, layer, name, color))
    return tuple(segments)


def label_mesh(volume: LabelVolume, label: int | Segment):
    """Watertight `trimesh.Trimesh` (world mm, RAS+, outward normals) of the voxels of ``label``
    (a value of the first layer, or a `Segment`).

    Raises `InputError` if the label has no voxel."""
    import trimesh
    from skimage.measure import marching_cubes

    segment = label if isinstance(label, Segment) else Segment(int(label))
    mask = volume.mask(segment)
    if not mask.any():
        raise InputError(f"{volume.source}: {segment.describe(volume.labels.shape[0])} has no voxel")
    padded = np.pad(mask, 1).astype(np.float32)
    verts, faces, _, _ = marching_cubes(padded, level=0.5)
    mesh = trimesh.Trimesh(volume.to_world(verts - 1.0), faces, process=True)
    if mesh.volume < 0:  # marching cubes' winding, or a mirroring affine, points the normals inward
        mesh.invert()
    trimesh.smoothing.filter_humphrey(mesh, iterations=SMOOTHING_ITERATIONS)
    if len(mesh.faces) > MAX_FACES:
        smaller = mesh.simplify_quadric_decimation(face_count=MAX_FACES)
        if smaller.is_watertight and smaller.is_volume:
            mesh = smaller
    return mesh
