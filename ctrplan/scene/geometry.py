"""Pose geometry of scenes: elementary rotations, 4x4 poses (local -> parent, mm) and the patient
directions of the `anatomy` key.
"""

from __future__ import annotations

import math

import numpy as np

#: Patient directions in pairs of opposites (the `anatomy` key of a scene).
ANATOMY_PAIRS = (("left", "right"), ("anterior", "posterior"), ("superior", "inferior"))

def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Fixed-axis roll (x), pitch (y), yaw (z), radians: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def frame_from_z(z_axis: np.ndarray, y_hint: np.ndarray | None = None) -> np.ndarray:
    """Rotation whose third column is ``z_axis``; the second column is ``y_hint`` made orthogonal."""
    z = np.asarray(z_axis, dtype=float)
    z = z / np.linalg.norm(z)
    if y_hint is None:
        y_hint = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = np.asarray(y_hint, dtype=float) - np.dot(y_hint, z) * z
    y = y / np.linalg.norm(y)
    x = np.cross(y, z)
    return np.column_stack([x, y, z])


def make_pose(rotation: np.ndarray, position: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = position
    return T


def transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply a 4x4 pose to points (..., 3)."""
    p = np.asarray(p, dtype=float)
    return p @ T[:3, :3].T + T[:3, 3]

def opposite(direction: str) -> str:
    """The patient direction opposite ``direction`` (e.g. left -> right)."""
    return next(b if a == direction else a for a, b in ANATOMY_PAIRS if direction in (a, b))
