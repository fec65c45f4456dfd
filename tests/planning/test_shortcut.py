"""Path shortcutting (`ctrplan.planning.shortcut`) against closed-form geometry: a disc obstacle in the
plane, where whether a straight move is free is the distance from the disc's centre to the segment."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from ctrplan.planning.shortcut import MAX_SPAN, shortcut_path

RADIUS = 1.0
RESOLUTION = 0.01


def _segment_clear(a: np.ndarray, b: np.ndarray) -> float:
    """Distance from the origin to the segment a-b, minus the disc's radius (closed form)."""
    d = b - a
    t = np.clip(-(a @ d) / (d @ d), 0.0, 1.0)
    return float(np.linalg.norm(a + t * d)) - RADIUS


def _arc_path(rng: np.random.Generator, k: int) -> np.ndarray:
    """A path of k vertices around the disc (upper half plane, radius 1.05-1.6 at random), from
    angle pi to 0: valid, and jagged."""
    angle = np.linspace(np.pi, 0.0, k)
    r = rng.uniform(1.05, 1.6, size=k)
    return np.stack([r * np.cos(angle), r * np.sin(angle)], axis=1)


def _brute_force(y: np.ndarray) -> float:
    """Length of the shortest path through y's vertices whose moves (at most MAX_SPAN vertices on)
    clear the disc, by exhaustive dynamic programming on the closed-form test."""
    k = len(y)
    best = np.full(k, np.inf)
    best[0] = 0.0
    for j in range(1, k):
        for i in range(max(0, j - MAX_SPAN), j):
            if j == i + 1 or _segment_clear(y[i], y[j]) > 0:
                best[j] = min(best[j], best[i] + np.linalg.norm(y[j] - y[i]))
    return float(best[-1])


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_shortcut_is_the_shortest_clear_path_through_the_vertices(seed):
    rng = np.random.default_rng(seed)
    for _ in range(100):  # a path none of whose moves grazes the disc: sampling then decides exactly
        y = _arc_path(rng, 14)  # (a move that dips 1e-3 into it has a chord of 0.09 inside, 9 states)
        if all(abs(_segment_clear(y[i], y[j])) > 1e-3 for i, j in itertools.combinations(range(14), 2)):
            break
    else:
        raise AssertionError("no path without grazing moves drawn")
    assert all(_segment_clear(a, b) > 0 for a, b in zip(y[:-1], y[1:], strict=True))  # a valid path
    calls = []

    def valid(states: np.ndarray) -> np.ndarray:
        calls.append(len(states))
        return np.linalg.norm(states, axis=1) > RADIUS

    cut = shortcut_path(y, valid, RESOLUTION)
    v = cut.vertices
    assert v[0] == 0 and v[-1] == len(y) - 1 and np.all(np.diff(v) > 0)
    assert all(_segment_clear(y[a], y[b]) > 0 for a, b in zip(v[:-1], v[1:], strict=True))
    length = float(np.linalg.norm(np.diff(y[v], axis=0), axis=1).sum())
    assert length == pytest.approx(_brute_force(y), rel=1e-9)
    assert length < float(np.linalg.norm(np.diff(y, axis=0), axis=1).sum())
    assert cut.calls == len(calls) and cut.states == sum(calls)
    # lazily: far fewer states than checking every candidate move at the resolution
    every = sum(int(np.ceil(np.linalg.norm(y[j] - y[i]) / RESOLUTION)) - 1
                for i, j in itertools.combinations(range(len(y)), 2) if 1 < j - i <= MAX_SPAN)
    assert cut.states < every / 3


def test_shortcut_checks_the_motion_validator_states():
    """A clear straight line becomes one move, checked at every interior state of ceil(length /
    resolution) equal pieces (the states of the single-state motion validator)."""
    y = np.stack([np.linspace(0.0, 1.0, 5), np.zeros(5)], axis=1)
    seen = []

    def valid(states: np.ndarray) -> np.ndarray:
        seen.append(states)
        return np.ones(len(states), dtype=bool)

    cut = shortcut_path(y, valid, 0.1)
    np.testing.assert_array_equal(cut.vertices, [0, 4])
    checked = np.round(np.concatenate(seen)[:, 0], 12)
    assert set(np.round(np.arange(1, 10) / 10, 12)) <= set(checked)  # the move 0 -> 4: 10 pieces
    assert len(shortcut_path(y[:2], valid, 0.1).vertices) == 2  # nothing to shortcut


def test_shortcut_keeps_a_path_whose_shortcuts_all_collide():
    """Around a disc with vertices just outside it, every shortcut crosses it: the path stays."""
    angle = np.linspace(np.pi, 0.0, 9)
    y = 1.02 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    assert all(_segment_clear(y[i], y[j]) < -0.02 for i in range(9) for j in range(i + 2, 9))
    cut = shortcut_path(y, lambda s: np.linalg.norm(s, axis=1) > RADIUS, RESOLUTION)
    np.testing.assert_array_equal(cut.vertices, np.arange(9))
