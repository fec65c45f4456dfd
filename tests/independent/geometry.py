"""Distances between a robot's surface and primitive obstacles, and rotations, written here (not with
ctrplan's scene or FCL): backbone points (..., 3) with their tube radius (...), mm."""

from __future__ import annotations

import math

import numpy as np


def axis_angle(axis, degrees: float) -> np.ndarray:
    """Rodrigues' rotation matrix (3, 3) about ``axis`` by ``degrees``."""
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = math.radians(degrees)
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


def sphere_gap(points: np.ndarray, radius: np.ndarray, center, sphere_radius: float) -> float:
    """Smallest distance from the robot's surface to a sphere (negative: overlap)."""
    return float((np.linalg.norm(points - np.asarray(center), axis=-1) - sphere_radius - radius).min())


def box_gap(points: np.ndarray, radius: np.ndarray, center, size, rotation=None) -> float:
    """Smallest distance from the robot's surface to a box (centre, full edge lengths, rotation
    box -> frame of the points); a point inside the box counts as 0 before its radius."""
    local = (points - np.asarray(center)) @ (np.eye(3) if rotation is None else np.asarray(rotation))
    outside = np.maximum(np.abs(local) - np.asarray(size) / 2, 0.0)
    return float((np.linalg.norm(outside, axis=-1) - radius).min())
