"""A scene from a segmentation: the template scene's obstacles replaced by one mesh per labelled
structure.

Which structures, under which names: a 3D Slicer ``.seg.nrrd`` names its segments (made valid
obstacle names: ``Right ICA`` -> ``Right_ICA``); NAMES.yaml names label values, renames segments
and gives margins::

    NAMES.yaml                         # label value (or a segment's name) -> obstacle name
    3: right_internal_carotid
    4: {name: sella_turcica}
    5: {name: left_internal_carotid, margin_mm: 2.0}   # the obstacle's own no-go margin (mm)
    Right ICA: {name: right_internal_carotid, margin_mm: 2.0}   # a segment, by the file's name
    Left ICA: {margin_mm: 2.0}                                 # keep its name

Every structure present in the volume must be named (by the file or NAMES.yaml): one that is not is
an error listing the unnamed labels, unless ``unnamed`` says ``skip`` (left out, with a warning
listing them) or ``keep`` (named ``label_<value>``). A name for a label without voxels is an error.

Frames: the volume is read into RAS+ world mm whatever its file's space
(`ctrplan.scene.segmentation`); the meshes are then written in the template's frame: the one its
``anatomy:`` key declares (a signed permutation of RAS, `ctrplan.scene.orientation`; the origin is
the volume's world origin), or RAS, which NEW.yaml then declares (``anatomy: {x: right, y: anterior,
z: superior}``). Each STL declares its frame in its header (``SPACE=...``, as 3D Slicer writes it).

The meshes are written as ``<NEW stem>_meshes/<name>.stl`` beside NEW.yaml; NEW.yaml is the template
with its ``obstacles`` replaced (robot, base pose, target, start, planner and the rest kept; a robot
file named relative to the template is renamed relative to NEW.yaml). Nothing is written unless
every structure meshes and the new scene loads; files already written are removed again when a
later step fails.
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

from ctrplan.base.dataio import atomic_write, check_output_dir, output_dir
from ctrplan.base.errors import InputError
from ctrplan.base.yamlio import YamlDoc, dump_yaml, load_yaml
from ctrplan.scene.loader import relocated, scene_from_yaml
from ctrplan.scene.objects import Scene
from ctrplan.scene.orientation import RAS, anatomy_code, code_anatomy, code_matrix, space_header
from ctrplan.scene.segmentation import LabelVolume, Segment, label_mesh, read_label_volume

_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
#: What to do with structures present in the volume that no name covers.
UNNAMED_POLICIES = ("error", "skip", "keep")


@dataclass(frozen=True)
class NamedLabel:
    """One entry of NAMES.yaml: a label value or a segment's name (``key``), the obstacle's name
    (None: the segment's own) and its own margin (mm)."""

    key: int | str
    name: str | None = None
    margin_mm: float | None = None
    where: str = ""  # file:line: key, for messages


@dataclass(frozen=True)
class Structure:
    """A structure of the volume and the obstacle it becomes."""

    segment: Segment
    name: str
    margin_mm: float | None = None


@dataclass(frozen=True)
class LabelImport:
    """What `scene_from_labels` made: the new scene, the volume, its structures (as obstacles), the
    ones left out (``unnamed skip``) and the frame the meshes were written in (a code, e.g. RAS)."""

    scene: Scene
    volume: LabelVolume
    structures: tuple[Structure, ...]
    skipped: tuple[Segment, ...]
    frame: str


def read_names(path: str | Path) -> tuple[NamedLabel, ...]:
    """The entries of a NAMES.yaml file (see the module docstring); errors name the line."""
    doc = load_yaml(path)
    if not isinstance(doc.data, dict):
        raise doc.error((), "expected a mapping of label values (or segment names) to obstacle names")
    named: list[NamedLabel] = []
    for key, spec in doc.data.items():
        keys = (str(key),)
        if isinstance(key, bool) or not isinstance(key, (int, str)) or (isinstance(key, int) and key <= 0):
            raise doc.error(keys, f"expected a positive integer label value or a segment name, got {key!r}")
        margin = None
        if isinstance(spec, dict):
            unknown = set(spec) - {"name", "margin_mm"}
            if unknown:
                raise doc.error(keys + (sorted(unknown)[0],), "unknown key (allowed: margin_mm, name)")
            margin = spec.get("margin_mm")
            if margin is not None and (isinstance(margin, bool) or not isinstance(margin, (int, float))
                                       or not math.isfinite(margin) or margin < 0):
                raise doc.error(keys + ("margin_mm",), f"expected a finite number >= 0 (mm), got {margin!r}")
            spec = spec.get("name")
        if spec is not None and (not isinstance(spec, str) or not _NAME.match(spec)):
            raise doc.error(keys, f"expected an obstacle name (letters, digits, _ . -), got {spec!r}")
        if spec is not None and any(n.name == spec for n in named):
            raise doc.error(keys, f"obstacle name {spec!r} is given to two labels")
        named.append(NamedLabel(key=key, name=spec, margin_mm=None if margin is None else float(margin),
                                where=doc.where(keys)))
    if not named:
        raise InputError(f"{path}: names no label")
    return tuple(named)


def obstacle_name(text: str) -> str:
    """A segment's name as a valid obstacle name (runs of other characters become ``_``)."""
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", text.strip()).strip("_.-")
    return name or "segment"


def structures(volume: LabelVolume, names: tuple[NamedLabel, ...], where: str,
               unnamed: str = "error") -> tuple[tuple[Structure, ...], tuple[Segment, ...]]:
    """The structures of ``volume`` as obstacles (file names, overridden by ``names``, read from
    ``where``) and the present ones left unnamed under ``unnamed`` = skip; `InputError` for a name
    of nothing, an ambiguous label value, or (``unnamed`` = error) any unnamed structure."""
    if unnamed not in UNNAMED_POLICIES:
        raise InputError(f"--unnamed: expected one of {', '.join(UNNAMED_POLICIES)}, got {unnamed!r}")
    present = volume.present()
    layers = volume.labels.shape[0]
    chosen: dict[Segment, NamedLabel] = {}
    for entry in names:
        segment = _named_segment(volume, present, entry, where)
        if segment in chosen:
            raise InputError(f"{entry.where}: {segment.describe(layers)} is named twice")
        chosen[segment] = entry
    out, skipped, missing = [], [], []
    for segment in present:
        entry = chosen.get(segment)
        name = entry.name if entry is not None and entry.name else \
            obstacle_name(segment.name) if segment.name else None
        if name is None and unnamed == "keep":
            name = f"label_{segment.value}" + (f"_layer{segment.layer}" if layers > 1 else "")
        if name is None:
            (skipped if unnamed == "skip" else missing).append(segment)
            continue
        out.append(Structure(segment, name, None if entry is None else entry.margin_mm))
    listed = ", ".join(s.describe(layers) for s in missing or skipped)
    if missing:
        raise InputError(f"{where}: {len(missing)} label(s) present in {volume.source} have no name: "
                         f"{listed} (name them, or pass --unnamed skip to leave them out or --unnamed keep)")
    if skipped:
        warnings.warn(f"{len(skipped)} label(s) present in {volume.source} are left out (--unnamed skip): "
                      f"{listed}", stacklevel=2)
    seen: dict[str, Segment] = {}
    for s in out:
        if s.name in seen:
            raise InputError(f"{where}: obstacle name {s.name!r} is given to {seen[s.name].describe(layers)} "
                             f"and {s.segment.describe(layers)}")
        seen[s.name] = s.segment
    if not out:
        raise InputError(f"{where}: no structure to mesh ({volume.source} has no labelled voxel)")
    return tuple(out), tuple(skipped)


def _named_segment(volume: LabelVolume, present: tuple[Segment, ...], entry: NamedLabel,
                   where: str) -> Segment:
    """The structure a NAMES.yaml entry names: a segment of that name, or the label value (in
    whichever layer holds it)."""
    layers = volume.labels.shape[0]
    if isinstance(entry.key, str):
        found = [s for s in volume.segments if s.name == entry.key]
        if not found:
            known = ", ".join(repr(s.name) for s in volume.segments) or "none"
            raise InputError(f"{entry.where}: {volume.source} has no segment of that name (its segments: "
                             f"{known})")
        segment = found[0]
        if segment not in present:
            raise InputError(f"{volume.source}: {segment.describe(layers)} has no voxel "
                             f"({entry.key!r} in {where})")
        return segment
    found = [s for s in present if s.value == entry.key]
    if len(found) > 1:
        raise InputError(f"{entry.where}: label {entry.key} is in layers "
                         f"{', '.join(str(s.layer) for s in found)} of {volume.source}: name the segments by "
                         f"their names instead")
    if not found:
        raise InputError(f"{volume.source}: label {entry.key} has no voxel ({entry.name or entry.key!r} "
                         f"in {where})")
    if entry.name is None and found[0].name is None:
        raise InputError(f"{entry.where}: label {entry.key} needs a name (the volume gives it none)")
    return found[0]


def scene_from_labels(labels: str | Path, names: str | Path | None, template: str | Path,
                      out: str | Path, unnamed: str = "error") -> LabelImport:
    """Write NEW.yaml (``out``) and its meshes (see the module docstring)."""
    out = Path(out)
    if out.suffix.lower() not in (".yaml", ".yml"):
        raise InputError(f"--out: {out} must be a .yaml file")
    if out.is_dir():
        raise InputError(f"--out: {out} is a directory, expected a scene file name")
    entries = read_names(names) if names is not None else ()
    template_doc = load_yaml(template)
    template_scene = scene_from_yaml(template_doc)  # a broken template is reported as such, before any work
    volume = read_label_volume(labels)
    if names is None and not volume.segments and unnamed == "error":
        raise InputError(f"--names: {volume.source} names none of its labels; give NAMES.yaml (label value "
                         f"-> obstacle name), or --unnamed keep to call them label_<value>")
    found, skipped = structures(volume, entries, str(names or labels), unnamed)
    frame = anatomy_code(template_scene.anatomy) if template_scene.anatomy else RAS
    to_frame = code_matrix(RAS, frame)
    meshes = {}
    for s in found:
        mesh = _mesh_of(volume, s, names or labels)
        mesh.vertices = mesh.vertices @ to_frame.T  # a rotation or reflection: winding fixed below
        if mesh.volume < 0:
            mesh.invert()
        meshes[s.name] = mesh
    check_output_dir(out.parent)
    mesh_dir = out.parent / f"{out.stem}_meshes"
    data = relocated(template_doc, out)
    data["obstacles"] = [{"name": s.name, "mesh": f"{mesh_dir.name}/{s.name}.stl"}
                         | ({} if s.margin_mm is None else {"margin_mm": s.margin_mm}) for s in found]
    data.setdefault("anatomy", code_anatomy(frame))
    created = [p for p in (mesh_dir, *mesh_dir.parents) if not p.exists()]
    written: list[Path] = []
    try:
        output_dir(mesh_dir)
        for name, mesh in meshes.items():
            written.append(mesh_dir / f"{name}.stl")
            with atomic_write(written[-1], "wb") as fh:
                fh.write(space_header(frame) + mesh.export(file_type="stl")[80:])
        scene = scene_from_yaml(YamlDoc(data=data, path=out, lines={}))
        with atomic_write(out) as fh:
            fh.write(f"# Made by `ctrplan scene from-labels` from {labels} ({volume.space} file, meshes in "
                     f"{frame}) and {names or 'its segment names'}; template {template}.\n" + dump_yaml(data))
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        for folder in created:  # deepest first; only the folders this call made
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
        raise
    return LabelImport(scene, volume, found, skipped, frame)


def _mesh_of(volume: LabelVolume, structure: Structure, names: str | Path):
    try:
        return label_mesh(volume, structure.segment)
    except InputError as exc:
        raise InputError(f"{exc} ({structure.name!r} in {names})") from None

