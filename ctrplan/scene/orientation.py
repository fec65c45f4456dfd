"""Patient directions of coordinate frames: which way is right, anterior, superior.

A frame is named by a three-letter code, one letter per axis (x, y, z) naming the patient direction
that axis points to: ``RAS`` (x right, y anterior, z superior: NIfTI's world and ctrplan's frame for
segmentations), ``LPS`` (DICOM, ITK, NRRD files from 3D Slicer), ``LSP`` (the skull-base scenes:
x left, y superior, z posterior). A scene's ``anatomy:`` key is the same information spelled out
(`anatomy_code`). Frames of one origin and different codes differ by a signed permutation
(`code_matrix`): RAS <-> LPS negates x and y, a 180-degree turn about the superior axis, which is
why a volume read in the wrong one of them looks plausible and is not.

Mesh files carry their frame the way 3D Slicer writes it (since 4.11): ``SPACE=RAS`` or
``SPACE=LPS`` in the STL header, a PLY or OBJ comment (`declared_space`, `space_header`).

`side_flips` judges a scene's orientation from its structures' names: a left/right (anterior/
posterior, superior/inferior) pair of one structure, e.g. ``left_internal_carotid`` and
``right_internal_carotid``, must lie that way round along the scene's declared axes.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

#: NIfTI's world frame and the frame of every label volume `ctrplan.scene.segmentation` reads.
RAS = "RAS"
#: Patient direction of each letter, and its unit vector in RAS.
LETTERS = {"R": "right", "L": "left", "A": "anterior", "P": "posterior", "S": "superior", "I": "inferior"}
_RAS_VECTOR = {"R": (1, 0, 0), "L": (-1, 0, 0), "A": (0, 1, 0), "P": (0, -1, 0), "S": (0, 0, 1),
               "I": (0, 0, -1)}
#: The positive direction of each pair of opposites, and their names.
_PAIRS = (("right", "left"), ("anterior", "posterior"), ("superior", "inferior"))
#: NRRD ``space`` values that name patient directions.
_NRRD_SPACES = {"right-anterior-superior": "RAS", "left-anterior-superior": "LAS",
                "left-posterior-superior": "LPS"}
_DECLARED = re.compile(rb"SPACE=([A-Za-z]{3})\b")
#: Name words that mark a side, per direction.
SIDE_WORDS = {"right": {"right", "r", "rt", "dexter"}, "left": {"left", "l", "lt", "sinister"},
              "anterior": {"anterior", "ant"}, "posterior": {"posterior", "post"},
              "superior": {"superior", "sup", "upper"}, "inferior": {"inferior", "inf", "lower"}}
#: A pair of structures closer than this (mm) along their axis says nothing about the side.
SIDE_TOLERANCE_MM = 1.0


def is_code(code: str) -> bool:
    """Whether ``code`` names one direction of each pair (e.g. RAS, LPS, LSP)."""
    code = code.upper()
    return (len(code) == 3 and all(c in LETTERS for c in code)
            and len({next(i for i, p in enumerate(("RL", "AP", "SI")) if c in p) for c in code}) == 3)


def parse_space(text: str) -> str | None:
    """The code of an NRRD ``space`` value (``left-posterior-superior``, ``LPS`` ...), None when it
    names no patient directions (``scanner-xyz``, ``3D-right-handed``, a time axis)."""
    text = str(text).strip()
    if text.lower() in _NRRD_SPACES:
        return _NRRD_SPACES[text.lower()]
    return text.upper() if is_code(text) else None


def axes_in_ras(code: str) -> np.ndarray:
    """Columns: the unit vectors (in RAS) of the frame's x, y, z axes (3, 3)."""
    return np.array([_RAS_VECTOR[c] for c in code.upper()], dtype=float).T


def code_matrix(source: str, target: str) -> np.ndarray:
    """The signed permutation (3, 3) taking coordinates in frame ``source`` to frame ``target``
    (same origin): ``p_target = M @ p_source``."""
    return axes_in_ras(target).T @ axes_in_ras(source)


def anatomy_code(anatomy: dict[str, str]) -> str:
    """The code of a scene's ``anatomy`` mapping ({x: left, y: superior, z: posterior} -> LSP)."""
    by_name = {v: k for k, v in LETTERS.items()}
    return "".join(by_name[anatomy[a]] for a in "xyz")


def code_anatomy(code: str) -> dict[str, str]:
    """The ``anatomy`` mapping of a code (RAS -> {x: right, y: anterior, z: superior})."""
    return {a: LETTERS[c] for a, c in zip("xyz", code.upper(), strict=True)}


def declared_space(path) -> str | None:
    """The frame a mesh file declares (3D Slicer's ``SPACE=RAS``/``SPACE=LPS`` in its first 1 kB:
    the STL header, a PLY or OBJ comment), or None."""
    with open(path, "rb") as fh:
        match = _DECLARED.search(fh.read(1024))
    code = match.group(1).decode().upper() if match else None
    return code if code and is_code(code) else None


def space_header(code: str) -> bytes:
    """An 80-byte binary STL header declaring frame ``code`` (read by `declared_space` and Slicer)."""
    return f"SPACE={code.upper()} written by ctrplan".encode().ljust(80, b" ")


def side_words(name: str) -> set[str]:
    """The directions a structure's name marks (``right_internal_carotid`` -> {right})."""
    words = {w.lower() for w in re.split(r"[^A-Za-z0-9]+|(?<=[a-z])(?=[A-Z])", name) if w}
    return {side for side, marks in SIDE_WORDS.items() if words & marks}


def _stem(name: str) -> str:
    words = [w.lower() for w in re.split(r"[^A-Za-z0-9]+|(?<=[a-z])(?=[A-Z])", name) if w]
    marks = set().union(*SIDE_WORDS.values())
    return "_".join(w for w in words if w not in marks)


@dataclass(frozen=True)
class SidePair:
    """Two structures of one name but opposite sides (``positive``: right/anterior/superior), and
    how far ``positive`` lies from ``negative`` toward its side along the scene's axes (mm;
    negative: the wrong way round)."""

    direction: str
    positive: str
    negative: str
    offset_mm: float

    @property
    def flipped(self) -> bool:
        return self.offset_mm < -SIDE_TOLERANCE_MM


def side_pairs(centroids: dict[str, np.ndarray], anatomy: dict[str, str]) -> list[SidePair]:
    """Every pair of structures (name -> centroid, scene frame) whose names differ only by the side
    they mark, with its offset along the scene's declared direction (``anatomy``)."""
    to_ras = axes_in_ras(anatomy_code(anatomy))  # columns: scene axes in RAS
    pairs = []
    for positive_side, negative_side in _PAIRS:
        axis = to_ras.T @ np.array(_RAS_VECTOR[next(k for k, v in LETTERS.items() if v == positive_side)],
                                   dtype=float)  # the positive direction in scene coordinates
        pair = {positive_side, negative_side}
        pos = {_stem(n): n for n in centroids if side_words(n) & pair == {positive_side}}
        neg = {_stem(n): n for n in centroids if side_words(n) & pair == {negative_side}}
        for stem in sorted(set(pos) & set(neg)):
            offset = float((centroids[pos[stem]] - centroids[neg[stem]]) @ axis)
            pairs.append(SidePair(positive_side, pos[stem], neg[stem], offset))
    return pairs


def flip_verdict(pairs: list[SidePair], anatomy: dict[str, str]) -> str | None:
    """What the wrong-way-round pairs say, in words (None if no pair is): a mirror image (one axis
    flipped), a half turn (two), or a point reflection (three); with the pairs as evidence."""
    flipped = {p.direction for p in pairs if p.flipped}
    right_way = {p.direction for p in pairs if p.offset_mm > SIDE_TOLERANCE_MM}
    if not flipped or flipped & right_way:
        return None  # no evidence, or the pairs disagree: say nothing rather than guess
    opposite = dict(_PAIRS)
    evidence = "; ".join(f"{p.positive} lies {-p.offset_mm:.1f} mm {opposite[p.direction]} of {p.negative}"
                         for p in pairs if p.flipped)
    names = " and ".join(f"{p}-{opposite[p]}" for p in sorted(flipped))
    if len(flipped) == 1:
        kind = f"mirrored {names}"
        if not right_way:  # nothing rules out a half turn about the third axis
            kind += (" (or turned half a turn with another axis flipped: an LPS file read as RAS, or "
                     "the reverse, flips left-right and anterior-posterior together)")
    elif len(flipped) == 2:
        (third,) = {p for p, _ in _PAIRS} - flipped
        kind = f"turned half a turn about the {third}-{opposite[third]} axis ({names} flipped" + \
               (": an LPS file read as RAS, or the reverse)" if third == "superior" else ")")
    else:
        kind = "mirrored through a point (every axis flipped)"
    return f"the anatomy is {kind}: {evidence} (scene axes: anatomy {anatomy_code(anatomy)})"
