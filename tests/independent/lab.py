"""Measured data with hidden effects, made by the independent integrator (`cosserat`) and effects
implemented here -- not by `ctrplan.model.causes`/`synthetic`.

Two acquisitions: a lab ``sweep`` (some joints sweep slowly back and forth -- small steps, reversals,
near-repeated configurations -- the others stay fixed) and ``random`` rows (every joint drawn anew in
the snap-free box for each row). A tracker with Gaussian noise sees the tips. Effects, with magnitudes
a real robot can have:

==================  ==================================================================  ==========
effect              how it is made here                                                 library?
==================  ==================================================================  ==========
registration        tracker frame rotated (Rodrigues) 1-2 deg and shifted 0.5-1 mm      yes
sensor_offset       tracked point 2-6 mm ahead of the tip of tube 1 along its tangent,  yes
                    <= 0.4 mm to the side (a coil sensor inside or on the tip)
bending_stiffness   tube 2 wall thicker: E and G of tube 2 x 1.3                        yes
curvature           pre-curvatures x (1 +- 5..12 %)                                     yes
stiffness_ratio     Poisson ratio of every tube 0.05-0.2 or 0.4-0.48 (G = E / 2(1+nu))  yes
backlash            alpha_i lags 1.5-3 deg behind the command in its direction of motion yes
joint_offset        zero offsets of the moving joints (1-2 mm, 2-4 deg)                 yes
betaK_offset        zero offset of beta_K alone, of the given size in mm (magnitude =   yes
                    the offset: true beta_K = reported + magnitude)
torsional_windup    friction torque 0.02-0.06 N mm twists tube 1..3 behind the plate:  yes
                    alpha_i lags tau / GJ_i * (-beta_i) in its direction of motion
transmission        each tube twists over 10-40 mm more than -beta_i (a compliant      yes
                    drive): psi_i = alpha_i - (beta_i - d_i) u_iz(0)
latency             the tracker 0.4-1 sample behind the joints: q_true = q - t (q - q_prev)  yes
                    (rotation steps the short way round)
friction            Jenkin elements (a spring, then a Coulomb slider breaking away after  yes
                    2 and 6 deg of travel) on every rotation, 1.5-3 deg of lag in all
curved_length       tube 1 bent to its drawn angle over a curve 4-8 mm off its drawn     yes (curvature)
                    length (kappa * curved length kept, total length kept)
relaxed_curvature   tube 2's curvature 52-58 % lower (a polymer tube that relaxed;      yes (only
                    implausible for nitinol)                                             polymer)
alpha_scale         rotation transmission ratio off by 4-6 % (alpha_true = s alpha)     no
encoder_wobble      eccentric rotation encoder: alpha_true = alpha + a sin(alpha)       no
stroke_offset       the tracked tip of tube 1 moves with the insertion of tube 1: a      no
                    fixed direction in the base frame, 0.8-1.2 mm over the stroke of
                    beta1 (a guide or cable that flexes as the tube advances)
==================  ==================================================================  ==========

`sessions` makes rows of several measurement sessions (a ``session`` column) whose registration or
tube-2 curvature differs between them.

Every true configuration is physical: joint offsets on a sweep are flipped or shrunk until it is;
random rows that an offset would make unphysical are drawn again.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace

import numpy as np

from tests.independent.cosserat import Tubes, solve

IN_LIBRARY = ("registration", "sensor_offset", "bending_stiffness", "curvature", "stiffness_ratio",
              "backlash", "joint_offset", "torsional_windup", "transmission")
#: Effects the library explains with a cause of another name: effect -> cause.
LIBRARY_CAUSE = {"curved_length": "curvature", "relaxed_curvature": "curvature"}
#: Effects of the library that only a sequence shows (rows acquired in order, not random rows).
IN_LIBRARY_SEQUENCE = ("latency", "friction")
#: Single-joint zero offsets: effect name -> the joint (index into q) it offsets; library cause joint_offset.
SINGLE_OFFSETS = {"beta1_offset": 0, "beta2_offset": 1, "beta3_offset": 2}
OUTSIDE = ("alpha_scale", "encoder_wobble", "stroke_offset")


#: The draw the tests use: fixed, so that a commit's test result never depends on its hash. The
#: variation over draws is `scripts/fuzz_diagnose.py`'s (every draw it finds failing becomes a pinned test).
FIXED_SEED = 1


def lab_seed() -> int:
    """CTRPLAN_TEST_SEED if set (to repeat a draw of `scripts/fuzz_diagnose.py`), else `FIXED_SEED`."""
    env = os.environ.get("CTRPLAN_TEST_SEED")
    return int(env) if env else FIXED_SEED


@dataclass
class LabData:
    q: np.ndarray               # commanded joints (n, 2N), mm / rad, acquisition order
    tips_mm: np.ndarray         # measured tips (n, N, 3)
    clean_mm: np.ndarray        # noiseless measured tips
    sigma_mm: float
    effects: dict = field(default_factory=dict)   # effect -> its true parameters
    session: np.ndarray | None = None             # (n,) the measurement session of every row (names)

    def write_csv(self, path, tubes=(0, 1, 2)) -> None:
        """The measured-data CSV (written here, not with ctrplan's writer), with a ``session`` column
        when the rows come from several sessions."""
        N = self.q.shape[1] // 2
        head = [f"beta{i + 1}" for i in range(N)] + [f"alpha{i + 1}" for i in range(N)]
        head += [f"tip{t + 1}_{a}" for t in tubes for a in "xyz"]
        head += [] if self.session is None else ["session"]
        lines = [",".join(head)]
        for r, (qr, tr) in enumerate(zip(self.q, self.tips_mm, strict=True)):
            cells = [f"{v:.9g}" for v in list(qr) + [tr[t, a] for t in tubes for a in range(3)]]
            lines.append(",".join(cells + ([] if self.session is None else [str(self.session[r])])))
        with open(path, "w") as fh:
            fh.write("\n".join(lines) + "\n")


def sweep(n: int, rng: np.random.Generator, moving=(1, 3, 4), step: float = 0.25) -> np.ndarray:
    """``n`` configurations of a three-tube robot: the ``moving`` joints (indices into q) sweep
    back and forth between random turning points in small steps; the others never move. Domain:
    -10 <= beta3 <= 0, beta3 - 55 <= beta2 <= beta3, beta2 - 15 <= beta1 <= beta2, |alpha| <= pi,
    kept 1 mm / 0.3 rad inside (and beta3 <= -3 mm)."""
    m = 1.0

    def interval(q: np.ndarray, j: int) -> tuple[float, float]:
        b1, b2, b3 = q[:3]
        if j == 0:
            return b2 - 15 + m, b2 - m
        if j == 1:
            return max(b3 - 55, b1) + m, min(b3, b1 + 15) - m
        if j == 2:
            return max(-10.0, b2) + m, min(-3.0, b2 + 55) - m
        return -2.8, 2.8

    b3 = rng.uniform(-8.0, -4.0)
    b2 = b3 - rng.uniform(10.0, 45.0)
    q = np.array([b2 - rng.uniform(4.0, 11.0), b2, b3, *rng.uniform(-2.5, 2.5, 3)])
    speed = np.array([0.6, 2.0, 0.3, 0.06, 0.06, 0.06]) * step / 0.25
    target = q.copy()
    out = np.empty((n, 6))
    for r in range(n):
        for j in moving:
            lo, hi = interval(q, j)
            if abs(target[j] - q[j]) < speed[j] or not lo <= target[j] <= hi:
                target[j] = rng.uniform(lo, hi)
            q[j] = np.clip(q[j] + np.sign(target[j] - q[j]) * speed[j] * rng.uniform(0.5, 1.5), lo, hi)
        out[r] = q
    return out


def random_rows(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` configurations (n, 6) drawn uniformly and independently in the paper's snap-free box:
    -10 <= beta3 <= 0, 0 <= beta3 - beta2 <= 55, 0 <= beta2 - beta1 <= 15, |alpha| <= pi."""
    b3 = rng.uniform(-10.0, 0.0, n)
    b2 = b3 - rng.uniform(0.0, 55.0, n)
    b1 = b2 - rng.uniform(0.0, 15.0, n)
    return np.column_stack([b1, b2, b3, rng.uniform(-np.pi, np.pi, (n, 3))])


def _physical_rows(q: np.ndarray, t: Tubes) -> np.ndarray:
    """Per row (n,): tube order, bases behind the plate, inner tubes reaching furthest (written apart)."""
    b = q[:, :3]
    e = b + t.length_mm
    return (b[:, 0] <= b[:, 1]) & (b[:, 1] <= b[:, 2]) & (b[:, 2] <= 0) & (e[:, 0] >= e[:, 1]) \
        & (e[:, 1] >= e[:, 2])


def _physical(q: np.ndarray, t: Tubes) -> bool:
    return bool(_physical_rows(q, t).all())


def _rodrigues(rv: np.ndarray) -> np.ndarray:
    th = np.linalg.norm(rv)
    if th == 0:
        return np.eye(3)
    k = rv / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def _directions(q: np.ndarray) -> np.ndarray:
    """+1/-1 for the latest move of each joint (0 before its first move), written apart."""
    d = np.zeros_like(q)
    last = np.zeros(q.shape[1])
    for r in range(1, len(q)):
        dq = q[r] - q[r - 1]
        last = np.where(dq > 0, 1.0, np.where(dq < 0, -1.0, last))
        d[r] = last
    return d


def make(n: int, effects: dict[str, float], seed: int, sigma_mm: float = 0.1, moving=(1, 3, 4),
         step: float = 0.25, rows: str = "sweep") -> LabData:
    """Lab data with the given hidden effects, each with a magnitude factor (1 = lab-sized,
    smaller: nearer the noise; for ``betaK_offset`` the offset in mm). ``rows``: ``sweep`` (the
    ``moving`` joints sweep) or ``random`` (every joint random in every row)."""
    rng = np.random.default_rng(seed)
    tubes = Tubes.paper()
    truth: dict = {}
    N = 3
    off = np.zeros(6)
    moved = range(6) if rows == "random" else moving
    for name, mag in effects.items():
        if name == "bending_stiffness":
            f = 1.0 + 0.3 * mag
            tubes = tubes.scaled(E=[1, f, 1], G=[1, f, 1])
            truth[name] = {"stiffness2_rel": f}
        elif name == "curvature":
            f = 1.0 + mag * rng.uniform(0.05, 0.12, 3) * rng.choice([-1, 1], 3)
            tubes = tubes.scaled(kappa_per_mm=f)
            truth[name] = {"kappa_factor": f.tolist()}
        elif name == "stiffness_ratio":
            nu0 = tubes.E[0] / (2 * tubes.G[0]) - 1
            target = rng.uniform(0.05, 0.2) if rng.random() < 0.5 else rng.uniform(0.4, 0.48)
            nu = nu0 + mag * (target - nu0)
            tubes = replace(tubes, G=tubes.E / (2 * (1 + nu)))
            truth[name] = {"poisson_ratio": float(nu)}
        elif name == "transmission":
            d = mag * rng.uniform(10.0, 40.0, 3)
            tubes = replace(tubes, transmission_mm=d)
            truth[name] = {"transmission_mm": d.tolist()}
        elif name == "curved_length":      # tube 1 bent to its angle over a curve 4-8 mm off its drawing
            shift = mag * rng.uniform(4.0, 8.0) * rng.choice([-1, 1])
            curved = tubes.curved_mm - [shift, 0, 0]
            tubes = replace(tubes, curved_mm=curved, straight_mm=tubes.straight_mm + [shift, 0, 0],
                            kappa_per_mm=tubes.kappa_per_mm * tubes.curved_mm / curved)
            truth[name] = {"curved_mm": tubes.curved_mm.tolist()}
        elif name == "relaxed_curvature":  # tube 2's curve relaxed by 52-58 % (a polymer tube)
            f = 1.0 - mag * rng.uniform(0.52, 0.58)
            tubes = tubes.scaled(kappa_per_mm=[1.0, f, 1.0])
            truth[name] = {"kappa2_factor": f}
        elif name == "joint_offset":
            for j in moved:
                off[j] = mag * (rng.uniform(1.0, 2.0) if j < N else math.radians(rng.uniform(2, 4))) \
                    * rng.choice([-1, 1])
        elif name in SINGLE_OFFSETS:
            off[SINGLE_OFFSETS[name]] = mag
    if rows == "random":      # draw rows until n of them are physical as commanded and as reached
        q = np.empty((0, 6))
        while len(q) < n:
            c = random_rows(2 * n, rng)
            q = np.concatenate([q, c[_physical_rows(c, tubes) & _physical_rows(c + off, tubes)]])
        q = q[:n]
    else:
        q = sweep(n, rng, moving, step)
        for _ in range(8):    # the true joints must be physical: else flip, then shrink
            if _physical(q + off, tubes):
                break
            off[:N] = -off[:N] if _physical(q + np.r_[-off[:N], off[N:]], tubes) else off[:N] / 2
    if off.any():
        truth["joint_offset"] = {"offset": off.tolist()}
    lags = _draw_lags(effects, rng, tubes, truth)

    def reached(q: np.ndarray) -> np.ndarray:
        return _reached(q, off, lags)

    with np.errstate(over="ignore", invalid="ignore"):   # rows past the snap of this robot diverge
        sol = solve(reached(q), tubes)
        for _ in range(20 if rows == "random" else 0):   # random rows: draw others for those
            failed = np.flatnonzero(~sol["converged"])
            if not failed.size:
                break
            c = random_rows(4 * failed.size, rng)
            c = c[_physical_rows(c, tubes) & _physical_rows(c + off, tubes)]
            q[failed[:len(c)]] = c[:failed.size]
            sol = solve(reached(q), tubes)
    assert sol["converged"].all()
    tips = sol["tips_mm"].copy()
    if "sensor_offset" in effects:
        side = rng.normal(size=2)
        dv = np.r_[side / np.linalg.norm(side) * rng.uniform(0.0, 0.4), rng.uniform(2.0, 6.0)] \
            * effects["sensor_offset"]
        tips[:, 0] += sol["tip_rotation"] @ dv
        truth["sensor_offset"] = {"offset_mm": dv.tolist()}
    if "stroke_offset" in effects:
        v = rng.normal(size=3)
        v = v / np.linalg.norm(v) * rng.uniform(0.8, 1.2) * effects["stroke_offset"]
        lo, hi = q[:, 0].min(), q[:, 0].max()
        tips[:, 0] += np.outer((q[:, 0] - lo) / max(hi - lo, 1e-9), v)
        truth["stroke_offset"] = {"offset_at_full_stroke_mm": v.tolist()}
    if "registration" in effects:
        mag = effects["registration"]
        ax = rng.normal(size=3)
        rv = ax / np.linalg.norm(ax) * math.radians(rng.uniform(1.0, 2.0)) * mag
        tv = rng.normal(size=3)
        tr = tv / np.linalg.norm(tv) * rng.uniform(0.5, 1.0) * mag
        tips = tips @ _rodrigues(rv).T + tr
        truth["registration"] = {"rotation_vector_rad": rv.tolist(), "translation_mm": tr.tolist()}
    noisy = tips + rng.normal(0.0, sigma_mm, tips.shape)
    return LabData(q=q, tips_mm=noisy, clean_mm=tips, sigma_mm=sigma_mm, effects=truth)


#: Half-widths (rad) of the lab's friction elements: springs with Coulomb sliders that break away after
#: 2 and 6 degrees of travel.
FRICTION_BREAKAWAY_RAD = (math.radians(2.0), math.radians(6.0))


def _draw_lags(effects: dict[str, float], rng: np.random.Generator, tubes: Tubes, truth: dict) -> dict:
    """The parameters of the joint-side effects (name -> value), their truth recorded in ``truth``."""
    N = 3
    lags: dict = {}
    for name, mag in effects.items():
        if name == "backlash":
            lags[name] = np.radians(rng.uniform(1.5, 3.0, N)) * mag
            truth[name] = {"backlash_rad": lags[name].tolist()}
        elif name == "torsional_windup":
            tau = rng.uniform(0.02, 0.06) * mag * np.array([1.0, 8.0, 40.0])   # N mm, ~ tube stiffness
            lags[name] = tau / tubes.gj
            truth[name] = {"friction_torque_nmm": tau.tolist()}
        elif name == "alpha_scale":
            lags[name] = 1.0 + mag * rng.uniform(0.04, 0.06) * rng.choice([-1, 1])
            truth[name] = {"scale": lags[name]}
        elif name == "encoder_wobble":
            lags[name] = mag * math.radians(rng.uniform(3.0, 5.0))
            truth[name] = {"amplitude_rad": lags[name]}
        elif name == "latency":            # the tracker 0.4-1 sample behind the joint log
            lags[name] = mag * rng.uniform(0.4, 1.0)
            truth[name] = {"latency_rows": lags[name]}
        elif name == "friction":           # per rotation: slip forces giving a 1.5-3 deg lag in all
            total = np.radians(rng.uniform(1.5, 3.0, N)) * mag
            share = rng.uniform(0.2, 0.8, N)
            lags[name] = np.stack([total * share, total * (1 - share)], axis=1)     # (N, 2) rad
            truth[name] = {"total_lag_rad": total.tolist(), "breakaway_rad": list(FRICTION_BREAKAWAY_RAD)}
    return lags


def _wrapped(d: np.ndarray) -> np.ndarray:
    """Angle differences taken the short way round, in (-pi, pi]."""
    return np.angle(np.exp(1j * d))


def _slip(alpha: np.ndarray, lag: np.ndarray) -> np.ndarray:
    """Lag (n, N) behind commanded angles alpha (n, N) of Jenkin elements (a spring, then a Coulomb
    slider that slips once the spring is stretched by the breakaway travel), element k of rotation i
    giving lag[i, k] when fully stretched; springs relaxed at the first row."""
    stretch = np.zeros(lag.shape)
    out = np.zeros(alpha.shape)
    for r in range(1, len(alpha)):
        move = _wrapped(alpha[r] - alpha[r - 1])
        for k, w in enumerate(FRICTION_BREAKAWAY_RAD):
            stretch[:, k] = np.clip(stretch[:, k] + move, -w, w)
        out[r] = (lag * stretch / np.array(FRICTION_BREAKAWAY_RAD)).sum(axis=1)
    return out


def _reached(q: np.ndarray, off: np.ndarray, lags: dict) -> np.ndarray:
    """The joints the tubes reach for reported joints q in acquisition order."""
    N = q.shape[1] // 2
    qt, d = q + off, _directions(q)
    for name, v in lags.items():
        if name == "backlash":
            qt[:, N:] -= v * d[:, N:]
        elif name == "torsional_windup":
            qt[:, N:] -= v * (-q[:, :N]) * d[:, N:]
        elif name == "alpha_scale":
            qt[:, N:] *= v
        elif name == "encoder_wobble":
            qt[:, N:] += v * np.sin(q[:, N:])
        elif name == "latency":
            before = np.concatenate([q[:1], q[:-1]])
            qt[:, :N] -= v * (q[:, :N] - before[:, :N])
            qt[:, N:] -= v * _wrapped(q[:, N:] - before[:, N:])
        elif name == "friction":
            qt[:, N:] -= _slip(q[:, N:], v)
    return qt


def sessions(n: int, seed: int, differs: str, names=("monday", "thursday"), sigma_mm: float = 0.1,
             moving=(1, 3, 4)) -> LabData:
    """``n`` rows in len(``names``) measurement sessions (a lab sweep each, one after another) of one
    robot whose ``differs`` changed between them: ``registration`` (the tracker re-registered: each
    session its own 1-2 deg / 0.5-1 mm registration) or ``curvature`` (tube 2's curvature relaxed
    between them, 8-12 % a session)."""
    rng = np.random.default_rng(seed)
    per = np.array_split(np.arange(n), len(names))
    q_all, tips_all, labels, truth = [], [], [], {differs: {}}
    for s, rows in enumerate(per):
        q = sweep(len(rows), rng, moving)
        tubes = Tubes.paper()
        if differs == "curvature":
            f = (1.0 - rng.uniform(0.08, 0.12)) ** s
            tubes = tubes.scaled(kappa_per_mm=[1.0, f, 1.0])
            truth[differs][names[s]] = {"kappa2_factor": f}
        sol = solve(q, tubes)
        assert sol["converged"].all()
        tips = sol["tips_mm"]
        if differs == "registration":
            ax, tv = rng.normal(size=3), rng.normal(size=3)
            rv = ax / np.linalg.norm(ax) * math.radians(rng.uniform(1.0, 2.0))
            tr = tv / np.linalg.norm(tv) * rng.uniform(0.5, 1.0)
            tips = tips @ _rodrigues(rv).T + tr
            truth[differs][names[s]] = {"rotation_vector_rad": rv.tolist(), "translation_mm": tr.tolist()}
        q_all.append(q)
        tips_all.append(tips)
        labels += [names[s]] * len(rows)
    clean = np.concatenate(tips_all)
    return LabData(q=np.concatenate(q_all), tips_mm=clean + rng.normal(0.0, sigma_mm, clean.shape),
                   clean_mm=clean, sigma_mm=sigma_mm, effects=truth, session=np.array(labels))


# ---- a lab that fails like real data -----------------------------------------------------------------
# What a third-party data set of a three-tube robot showed (1,307 rows in acquisition order, EM tracker on
# the tip of tube 1 only): beta2, beta3 and alpha3 never move; alpha1 and alpha2 lag 1.7 and 4.4 deg
# behind the command in the direction of motion (backlash plus hysteresis); the tracker registration is
# about 9 mm and 4 deg; 0.24 mm noise. `real_like` makes data of that kind.

#: The real data's figures the lab reproduces (tube-1 tip, last 30 % held out, mm).
REAL_LAG_DEG = (1.7, 4.4)           # total lag of alpha1, alpha2 after a long move in one direction
REAL_REGISTRATION = (9.0, 4.0)      # tracker translation mm, rotation deg
REAL_SIGMA_MM = 0.24
REAL_ROWS = 1307
#: The share of each lag that is play (a dead band: after a reversal the tube does not turn until the
#: drive has crossed twice this); the rest is hysteresis that builds up over `HYSTERESIS_SCALE_RAD`.
PLAY_SHARE = 0.6
HYSTERESIS_SCALE_RAD = math.radians(3.0)


def play_lag(x: np.ndarray, half_width: float) -> np.ndarray:
    """Lag (n,) rad of a play (backlash) operator behind the commanded angle sequence x (n,): the output
    y follows x only when it is more than ``half_width`` away, y_k = clip(y_(k-1), x_k - w, x_k + w),
    y_0 = x_0; lag = x - y, in [-w, w]."""
    y, out = x[0], np.empty_like(x)
    for k, xk in enumerate(x):
        y = min(max(y, xk - half_width), xk + half_width)
        out[k] = xk - y
    return out


def hysteresis_lag(x: np.ndarray, amplitude: float, scale: float) -> np.ndarray:
    """Lag (n,) rad of a first-order (Dahl-type) hysteresis behind the commanded angles x (n,): on a
    move dx it relaxes to sign(dx) * amplitude as h <- s a + (h - s a) exp(-|dx| / scale); 0 at start."""
    h, out = 0.0, np.zeros_like(x)
    for k in range(1, len(x)):
        dx = x[k] - x[k - 1]
        if dx:
            target = math.copysign(amplitude, dx)
            h = target + (h - target) * math.exp(-abs(dx) / scale)
        out[k] = h
    return out


def walk(n: int, rng: np.random.Generator, fixed: dict[int, float], speed=(0.35, 0.0, 0.0, 0.035, 0.035, 0.0),
         turn: float = 0.04) -> np.ndarray:
    """``n`` rows (n, 6) of a random walk with momentum: each moving joint keeps its direction and
    reverses with probability ``turn`` per row (and at its limits), its step ``speed`` (mm / rad)
    times a factor in [0.3, 1.7]; the ``fixed`` joints (index -> value) never move. Limits: beta1 in
    [beta2 - 14, beta2 - 1] mm, alpha in [-2.8, 2.8] rad."""
    q = np.array([fixed.get(j, 0.0) for j in range(6)])
    lo = np.array([q[1] - 14.0, 0, 0, -2.8, -2.8, -2.8])
    hi = np.array([q[1] - 1.0, 0, 0, 2.8, 2.8, 2.8])
    moving = [j for j in range(6) if j not in fixed]
    q[moving] = rng.uniform(lo[moving], hi[moving])
    sign = rng.choice([-1.0, 1.0], 6)
    out = np.empty((n, 6))
    for r in range(n):
        for j in moving:
            nxt = q[j] + sign[j] * speed[j] * rng.uniform(0.3, 1.7)
            if rng.random() < turn or not lo[j] <= nxt <= hi[j]:
                sign[j] = -sign[j]
                nxt = q[j] + sign[j] * speed[j] * rng.uniform(0.3, 1.7)
            q[j] = float(np.clip(nxt, lo[j], hi[j]))
        out[r] = q
    return out


def real_like(n: int = REAL_ROWS, seed: int = 0, curvature: tuple = (1.08, 0.94, 1.0),
              lag_deg: tuple = REAL_LAG_DEG, registration: tuple = REAL_REGISTRATION,
              sigma_mm: float = REAL_SIGMA_MM) -> LabData:
    """Data like the real set: beta2 = -30, beta3 = -5 mm and alpha3 = 0.3 rad fixed; beta1, alpha1 and
    alpha2 random-walk (`walk`); tube pre-curvatures scaled by ``curvature``; alpha1, alpha2 lag
    ``lag_deg`` (`PLAY_SHARE` play, the rest hysteresis); a tracker rotated ``registration[1]`` deg and
    shifted ``registration[0]`` mm; Gaussian noise ``sigma_mm`` per coordinate. Write it with
    ``write_csv(path, tubes=(0,))``: only the tip of tube 1 is measured."""
    rng = np.random.default_rng(seed)
    tubes = Tubes.paper().scaled(kappa_per_mm=np.asarray(curvature, dtype=float))
    q = walk(n, rng, {1: -30.0, 2: -5.0, 5: 0.3})
    reached = q.copy()
    for i, lag in zip((3, 4), np.radians(lag_deg), strict=True):
        reached[:, i] -= play_lag(q[:, i], PLAY_SHARE * lag) \
            + hysteresis_lag(q[:, i], (1 - PLAY_SHARE) * lag, HYSTERESIS_SCALE_RAD)
    sol = solve(reached, tubes)
    assert sol["converged"].all()
    axis, shift = rng.normal(size=3), rng.normal(size=3)
    rv = axis / np.linalg.norm(axis) * math.radians(registration[1])
    tr = shift / np.linalg.norm(shift) * registration[0]
    tips = sol["tips_mm"] @ _rodrigues(rv).T + tr
    truth = {"curvature": {"kappa_factor": list(curvature)},
             "lag": {"total_deg": list(lag_deg), "play_share": PLAY_SHARE,
                     "hysteresis_scale_rad": HYSTERESIS_SCALE_RAD},
             "registration": {"rotation_vector_rad": rv.tolist(), "translation_mm": tr.tolist()},
             "fixed": {"beta2": -30.0, "beta3": -5.0, "alpha3": 0.3}}
    noisy = tips + rng.normal(0.0, sigma_mm, tips.shape)
    return LabData(q=q, tips_mm=noisy, clean_mm=tips, sigma_mm=sigma_mm, effects=truth)
