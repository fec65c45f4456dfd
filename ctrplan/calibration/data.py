"""Measured tip data: readers for the measured-data CSV and the CRL 40-column format, and writers.

Rows keep their acquisition order (direction-dependent effects need it) and their line numbers in
the source file, so every message can name the row: ``row N`` is line N of the file (a header, if
any, is line 1) -- the same convention as the other ctrplan readers.

Bad input raises `InputError` naming the file, the row(s) and the field. Configurations outside the
snap-free planning domain are accepted and flagged (``MeasuredData.outside_domain``); physically
impossible ones are rejected.
"""

from __future__ import annotations

import csv
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ctrplan.base.dataio import (
    atomic_write,
    format_csv,
    joint_names,
    parse_number,
    parse_table,
    read_text,
    tip_names,
)
from ctrplan.base.errors import InputError
from ctrplan.model.motion import Motion
from ctrplan.model.robot import Robot, check_joint_rows
from ctrplan.model.sessions import SESSION_COLUMN

CRL_COLUMNS = 40
#: Order of the joints in a CRL row: alpha1 beta1 alpha2 beta2 alpha3 beta3 -> index into q.
CRL_JOINT_ORDER = (3, 0, 4, 1, 5, 2)
#: CRL sensors after the base: outer (tube 3), middle (tube 2), inner (tube 1).
CRL_SENSOR_TUBE = (2, 1, 0)
MIN_ROWS = 30


@dataclass(frozen=True)
class MeasuredData:
    """Joint configurations and measured tube tips, in acquisition order.

    Attributes:
        q: commanded joints (N, 6), mm and rad.
        tips_mm: measured tips of tubes 1..3 (N, 3, 3), mm; NaN for a tube that was not measured.
        tubes: indices (0-based) of the measured tubes, e.g. ``(0,)`` or ``(0, 1, 2)``.
        lines: line number of each row in the source file (N,).
        source: file name (for messages).
        format: ``"csv"`` (measured-data CSV) or ``"crl"`` (CRL-Dataset-CTCR-Pose).
        outside_domain: rows outside the snap-free domain (N,) -- accepted, flagged.
        increments: the CRL joint increments (N, 6) in q order, if the file had them.
        session: the measurement session of every row (N,) -- the optional ``session`` column, any name
            or number as text -- or None (one session). A session is a sequence of its own: its motion
            history starts with its first row (`motion`).
    """

    q: np.ndarray
    tips_mm: np.ndarray
    tubes: tuple[int, ...]
    lines: np.ndarray
    source: str = "<memory>"
    format: str = "csv"
    outside_domain: np.ndarray = field(default=None)  # type: ignore[assignment]
    increments: np.ndarray | None = None
    session: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.outside_domain is None:
            object.__setattr__(self, "outside_domain", np.zeros(len(self.q), dtype=bool))

    def __len__(self) -> int:
        return self.q.shape[0]

    def subset(self, idx: np.ndarray) -> MeasuredData:
        inc = None if self.increments is None else self.increments[idx]
        return MeasuredData(q=self.q[idx], tips_mm=self.tips_mm[idx], tubes=self.tubes,
                            lines=self.lines[idx], source=self.source, format=self.format,
                            outside_domain=self.outside_domain[idx], increments=inc,
                            session=None if self.session is None else self.session[idx])

    @property
    def sessions(self) -> tuple[str, ...]:
        """The measurement sessions, in the order of their first rows (empty: one session)."""
        if self.session is None:
            return ()
        names, first = np.unique(self.session, return_index=True)
        return tuple(str(v) for v in names[np.argsort(first)])

    def motion(self) -> Motion:
        """The motion history of the rows (`Motion.of`; each session its own sequence)."""
        return Motion.of(self.q, session=self.session)

    def rows_text(self, idx, limit: int = 8) -> str:
        """``"rows 5, 9, 12 (and 3 more)"`` for row indices ``idx`` (0-based into this data)."""
        return rows_text(self.lines[np.asarray(idx, dtype=int)], limit)


def rows_text(lines, limit: int = 8) -> str:
    lines = [int(v) for v in lines]
    head = ", ".join(str(v) for v in lines[:limit])
    more = f" (and {len(lines) - limit} more)" if len(lines) > limit else ""
    return f"row{'s' if len(lines) != 1 else ''} {head}{more}"


# ---- reading ------------------------------------------------------------------------------------
def _split_fields(line: str) -> list[str]:
    if "," in line:
        return [c.strip() for c in next(csv.reader([line]))]
    if ";" in line:
        return [c.strip() for c in line.split(";")]
    return line.split()


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_measured(path: str | Path, robot: Robot | None = None, *,
                  min_rows: int = MIN_ROWS) -> MeasuredData:
    """Read measured tip data, detecting the format: a header with ``beta1..alpha3,tip1_x..`` (the
    measured-data CSV) or 40 numeric columns without a header (CRL-Dataset-CTCR-Pose).

    Joints are checked against ``robot`` (nominal if None): physically impossible rows are an error,
    rows outside the snap-free domain are accepted and flagged.
    """
    path = Path(path)
    robot = robot or Robot.nominal()
    joints = robot.joint_names
    text = read_text(path)
    head = next(((n, ln) for n, ln in enumerate(text.splitlines(), start=1) if ln.strip()), None)
    if head is None:
        raise InputError(f"{path}: empty file (expected a header line "
                         f"{','.join(joints)},tip1_x,tip1_y,tip1_z or 40-column CRL rows)")
    head_line, first = head
    fields_ = _split_fields(first)
    if any(f in joints for f in fields_):
        data = _parse_measured_csv(path, text, head_line, robot.n_tubes)
    elif all(_is_number(f) for f in fields_) and robot.n_tubes != 3:
        raise InputError(f"{path}: row {head_line}: CRL-Dataset-CTCR-Pose rows are for three-tube robots, "
                         f"robot {robot.name!r} has {robot.n_tubes}; give a header ({','.join(joints)},...)")
    elif all(_is_number(f) for f in fields_):
        if len(fields_) != CRL_COLUMNS:
            raise InputError(f"{path}: row {head_line}: no header and {len(fields_)} numeric columns; "
                             f"expected a header ({','.join(joints)},tip1_x,...) or the "
                             f"{CRL_COLUMNS} columns of the CRL-Dataset-CTCR-Pose format")
        data = _parse_crl(path, text)
    else:
        raise InputError(f"{path}: row {head_line}: header lacks the joint columns "
                         f"{','.join(joints)} (got: {','.join(fields_)})")
    return _validate(data, robot, min_rows)


def _parse_measured_csv(path: Path, text: str, head_line: int, n_tubes: int = 3) -> MeasuredData:
    tip_columns = tuple(tip_names(n_tubes)[3 * t: 3 * t + 3] for t in range(n_tubes))
    table = parse_table(text, path, joint_names(n_tubes) + tip_columns[0],
                        optional=sum(tip_columns[1:], ()), allow_missing=True, n_tubes=n_tubes,
                        labels=(SESSION_COLUMN,))
    tubes = [0]
    for t in range(1, n_tubes):
        present = [c in table.columns for c in tip_columns[t]]
        if any(present) and not all(present):
            lack = [c for c, p in zip(tip_columns[t], present, strict=True) if not p]
            raise InputError(f"{path}: row {head_line}: tube {t + 1} tip is incomplete: missing column"
                             f"{'s' if len(lack) > 1 else ''} {', '.join(repr(c) for c in lack)}")
        if all(present):
            tubes.append(t)
    _raise_nonfinite(path, table.values, table.lines, table.columns)
    tips = np.full((len(table.values), n_tubes, 3), np.nan)
    for t in tubes:
        tips[:, t, :] = table.values[:, [table.columns.index(c) for c in tip_columns[t]]]
    return MeasuredData(q=table.joints, tips_mm=tips, tubes=tuple(tubes), lines=table.lines,
                        source=str(path), format="csv", session=table.labels.get(SESSION_COLUMN))


def _raise_nonfinite(path: Path, values: np.ndarray, lines: np.ndarray, names: Sequence[str]) -> None:
    """`InputError` naming every row of ``values`` (R, C) with a NaN or infinite value."""
    bad = ~np.isfinite(values)
    rows = np.flatnonzero(bad.any(axis=1))
    if len(rows):
        first = names[int(np.argmax(bad[rows[0]]))]
        raise InputError(f"{path}: {rows_text(lines[rows])}: missing or non-finite values "
                         f"(first: {first} in row {lines[rows[0]]}); fix or remove these rows")


def quaternion_matrix(qwxyz: np.ndarray) -> np.ndarray:
    """Scalar-first quaternions (..., 4), normalised here -> rotation matrices (..., 3, 3)."""
    from ctrplan.kinematics.backbone import quaternion_to_matrix  # lazy: ctrplan.kinematics loads numba

    q = np.asarray(qwxyz, dtype=float)
    return quaternion_to_matrix(q / np.linalg.norm(q, axis=-1, keepdims=True))


def matrix_quaternion(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> scalar-first unit quaternions (..., 4) (w >= 0)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=float)
    xyzw = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    wxyz = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    wxyz *= np.where(wxyz[:, :1] < 0, -1.0, 1.0)
    return wxyz.reshape(R.shape[:-2] + (4,))


def _parse_crl(path: Path, text: str) -> MeasuredData:
    values, lines = [], []
    for line_no, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        cells = _split_fields(line)
        if len(cells) != CRL_COLUMNS:
            raise InputError(f"{path}: row {line_no}: expected {CRL_COLUMNS} columns (CRL format), "
                             f"got {len(cells)}")
        values.append([parse_number(cell, path, line_no, label, allow_missing=True)
                       for cell, label in zip(cells, CRL_LABELS, strict=True)])
        lines.append(line_no)
    arr = np.array(values, dtype=float)
    lines = np.array(lines, dtype=np.int64)
    _raise_nonfinite(path, arr, lines, CRL_NAMES)
    q = np.empty((len(arr), 6))
    inc = np.empty((len(arr), 6))
    for c, j in enumerate(CRL_JOINT_ORDER):
        q[:, j] = arr[:, c]
        inc[:, j] = arr[:, 6 + c]
    poses = arr[:, 12:40].reshape(len(arr), 4, 7)
    qn = np.linalg.norm(poses[..., 3:], axis=-1)
    zero = np.argwhere(qn < 1e-9)
    if len(zero):
        r, s = zero[0]
        sensor = ("base", "outer", "middle", "inner")[s]
        raise InputError(f"{path}: row {lines[r]}: {sensor} sensor quaternion is zero")
    R_base = quaternion_matrix(poses[:, 0, 3:])
    p_base = poses[:, 0, :3]
    tips = np.empty((len(arr), 3, 3))
    for s, tube in enumerate(CRL_SENSOR_TUBE, start=1):
        # inv(T_base) * T_sensor: position part R_base^T (p_sensor - p_base)
        tips[:, tube] = np.einsum("nji,nj->ni", R_base, poses[:, s, :3] - p_base)
    return MeasuredData(q=q, tips_mm=tips, tubes=(0, 1, 2), lines=lines, source=str(path),
                        format="crl", increments=inc)


def _crl_name(c: int) -> str:
    joints = ("alpha1", "beta1", "alpha2", "beta2", "alpha3", "beta3")
    if c < 6:
        return joints[c]
    if c < 12:
        return f"d{joints[c - 6]}"
    sensor = ("base", "outer", "middle", "inner")[(c - 12) // 7]
    return f"{sensor}_{('x', 'y', 'z', 'qw', 'qx', 'qy', 'qz')[(c - 12) % 7]}"


#: Names of the CRL columns, and their labels in messages (``column 7 (dalpha1)``).
CRL_NAMES = tuple(_crl_name(c) for c in range(CRL_COLUMNS))
CRL_LABELS = tuple(f"column {c + 1} ({name})" for c, name in enumerate(CRL_NAMES))


def _validate(data: MeasuredData, robot: Robot, min_rows: int) -> MeasuredData:
    q = data.q
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_joint_rows(robot, q, data.lines, data.source, allow_outside_domain=True)
    outside = np.zeros(len(q), dtype=bool)
    for r, _ in robot.domain.violations(q):
        outside[r] = True
    if len(q) < min_rows:
        raise InputError(f"{data.source}: only {len(q)} data rows; diagnosing needs at least {min_rows} "
                         f"(more is better: a few hundred rows)")
    return MeasuredData(q=q, tips_mm=data.tips_mm, tubes=data.tubes, lines=data.lines,
                        source=data.source, format=data.format, outside_domain=outside,
                        increments=data.increments, session=data.session)


# ---- writing ------------------------------------------------------------------------------------
def write_measured_csv(path: str | Path, q: np.ndarray, tips_mm: np.ndarray,
                       tubes: tuple[int, ...] | None = None,
                       extra: dict[str, np.ndarray] | None = None) -> None:
    """Write the measured-data CSV: joints (R, 2N), then the tips (R, N, 3) of ``tubes`` (0-based; all
    if None), then ``extra`` columns."""
    q = np.asarray(q, dtype=float)
    n = q.shape[1] // 2
    tubes = tuple(range(n)) if tubes is None else tubes
    names = tip_names(n)
    header = list(joint_names(n)) + [names[3 * t + a] for t in tubes for a in range(3)] + list(extra or {})
    cols = [q] + [tips_mm[:, t, :] for t in tubes] + [np.asarray(v)[:, None] for v in (extra or {}).values()]
    table = np.concatenate(cols, axis=1)
    with atomic_write(path) as fh:
        fh.write(format_csv(header, table, ["%r"] * len(header)))


def write_crl_csv(path: str | Path, q: np.ndarray, tips_mm: np.ndarray, base_pose: np.ndarray | None = None,
                  increments: np.ndarray | None = None, rng: np.random.Generator | int | None = None) -> None:
    """Write a CRL-Dataset-CTCR-Pose-style file (40 columns, no header) from robot-frame tips.

    ``base_pose`` (4, 4) places the base sensor in the tracker frame (identity if None); the tube
    sensors get ``T_base @ [R_i, tip_i]`` with random orientations ``R_i`` (orientations are not used
    by ctrplan). ``increments`` default to the difference to the previous row.
    """
    rng = np.random.default_rng(rng)
    q = np.asarray(q, dtype=float)
    n = len(q)
    T = np.eye(4) if base_pose is None else np.asarray(base_pose, dtype=float)
    if increments is None:
        increments = np.diff(q, axis=0, prepend=q[:1])
    out = np.empty((n, CRL_COLUMNS))
    for c, j in enumerate(CRL_JOINT_ORDER):
        out[:, c] = q[:, j]
        out[:, 6 + c] = increments[:, j]
    qb = matrix_quaternion(T[:3, :3])
    out[:, 12:15] = T[:3, 3]
    out[:, 15:19] = qb
    for s, tube in enumerate(CRL_SENSOR_TUBE, start=1):
        p = tips_mm[:, tube] @ T[:3, :3].T + T[:3, 3]
        quat = rng.normal(size=(n, 4))
        quat /= np.linalg.norm(quat, axis=1, keepdims=True)
        out[:, 12 + 7 * s: 15 + 7 * s] = p
        out[:, 15 + 7 * s: 19 + 7 * s] = quat
    with atomic_write(path) as fh:
        fh.write(format_csv(None, out, ["%r"] * CRL_COLUMNS))
