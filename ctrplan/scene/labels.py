"""A scene from a segmentation: the template scene's obstacles replaced by one mesh per named label.

    NAMES.yaml                         # label value -> obstacle name
    3: right_internal_carotid
    4: {name: sella_turcica}
    5: {name: left_internal_carotid, margin_mm: 2.0}   # the obstacle's own no-go margin (mm)

The meshes (`ctrplan.scene.segmentation.label_mesh`, world mm of the volume's affine) are written as
``<NEW stem>_meshes/<name>.stl`` beside NEW.yaml; NEW.yaml is the template with only its
``obstacles`` replaced (robot, base pose, target, start, planner and the rest kept; a robot file
named relative to the template is renamed relative to NEW.yaml). The template's frame must be the
volume's world frame (for NIfTI: RAS+, mm). Nothing is written unless every label meshes and the
new scene loads; files already written are removed again when a later step fails.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from ctrplan.base.dataio import atomic_write, check_output_dir, output_dir
from ctrplan.base.errors import InputError
from ctrplan.base.yamlio import YamlDoc, dump_yaml, load_yaml
from ctrplan.scene.loader import relocated, scene_from_yaml
from ctrplan.scene.objects import Scene
from ctrplan.scene.segmentation import LabelVolume, label_mesh, read_label_volume

_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


@dataclass(frozen=True)
class NamedLabel:
    """One label value of the volume and the obstacle it becomes."""

    value: int
    name: str
    margin_mm: float | None = None


def read_names(path: str | Path) -> tuple[NamedLabel, ...]:
    """The label names of a NAMES.yaml file (see the module docstring); errors name the line."""
    doc = load_yaml(path)
    named: list[NamedLabel] = []
    for key, spec in doc.data.items():
        keys = (str(key),)
        if isinstance(key, bool) or not isinstance(key, int) or key <= 0:
            raise doc.error(keys, f"expected a positive integer label value, got {key!r}")
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
        if not isinstance(spec, str) or not _NAME.match(spec):
            raise doc.error(keys, f"expected an obstacle name (letters, digits, _ . -), got {spec!r}")
        if any(n.name == spec for n in named):
            raise doc.error(keys, f"obstacle name {spec!r} is given to two labels")
        named.append(NamedLabel(value=key, name=spec, margin_mm=None if margin is None else float(margin)))
    if not named:
        raise InputError(f"{path}: names no label")
    return tuple(named)


def scene_from_labels(labels: str | Path, names: str | Path, template: str | Path,
                      out: str | Path) -> tuple[Scene, LabelVolume]:
    """Write NEW.yaml (``out``) and its meshes; return the loaded new scene and the volume."""
    out = Path(out)
    if out.suffix.lower() not in (".yaml", ".yml"):
        raise InputError(f"--out: {out} must be a .yaml file")
    if out.is_dir():
        raise InputError(f"--out: {out} is a directory, expected a scene file name")
    named = read_names(names)
    template_doc = load_yaml(template)
    scene_from_yaml(template_doc)  # a broken template is reported as such, before any work
    volume = read_label_volume(labels)
    meshes = {n.name: _mesh_of(volume, n, names) for n in named}
    check_output_dir(out.parent)
    mesh_dir = out.parent / f"{out.stem}_meshes"
    data = relocated(template_doc, out)
    data["obstacles"] = [{"name": n.name, "mesh": f"{mesh_dir.name}/{n.name}.stl"}
                         | ({} if n.margin_mm is None else {"margin_mm": n.margin_mm}) for n in named]
    created = [p for p in (mesh_dir, *mesh_dir.parents) if not p.exists()]
    written: list[Path] = []
    try:
        output_dir(mesh_dir)
        for name, mesh in meshes.items():
            written.append(mesh_dir / f"{name}.stl")
            with atomic_write(written[-1], "wb") as fh:
                fh.write(mesh.export(file_type="stl"))
        scene = scene_from_yaml(YamlDoc(data=data, path=out, lines={}))
        with atomic_write(out) as fh:
            fh.write(f"# Made by `ctrplan scene from-labels` from {labels} and {names}; template "
                     f"{template}.\n" + dump_yaml(data))
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        for folder in created:  # deepest first; only the folders this call made
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
        raise
    return scene, volume


def _mesh_of(volume: LabelVolume, named: NamedLabel, names: str | Path):
    try:
        return label_mesh(volume, named.value)
    except InputError as exc:
        raise InputError(f"{exc} ({named.name!r} in {names})") from None
