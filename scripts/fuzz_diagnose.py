#!/usr/bin/env python
"""Property draws of `ctrplan diagnose` on lab data (`tests/independent/lab.py`: its own integrator and
effects): many draws of hidden effects, acquisitions, row counts, noise levels, measured tubes and
measurement sessions, each diagnosed, each checked for the properties every diagnosis must have --
whatever the fitter tries (a joint offset that pulls a tube behind the plate, a solver that does not
converge, a NaN), it finishes with a verdict and a JSON document without a non-finite number.

    nice -n 10 python scripts/fuzz_diagnose.py --seeds 0-199 [--all-candidates] [--out fuzz.json]

CI does not run it (a draw takes seconds to a minute); the tests draw fixed seeds (`lab.lab_seed`), and
every draw this script finds failing is pinned there as a regression test (CTRPLAN_TEST_SEED repeats a
test's draw). Properties: no exception; ``cause`` one of the library's names (or none, undetermined,
unexplained); every named cause among the candidates; the JSON document serialisable without NaN;
the extended model no worse on the held-out rows than the nominal one when a cause is named. Also
recorded (statistics, not failures): whether the named set is the hidden one.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # tests.independent

from ctrplan.calibration import CAUSES, DiagnoseOptions, diagnose, read_measured  # noqa: E402
from ctrplan.model.causes.base import PER_SESSION  # noqa: E402
from tests.independent.lab import (  # noqa: E402
    IN_LIBRARY,
    IN_LIBRARY_SEQUENCE,
    LIBRARY_CAUSE,
    OUTSIDE,
    make,
    sessions,
)

VERDICTS = {"none", "undetermined", "unexplained"}


def draw(seed: int) -> dict:
    """One case: hidden effects (0-2 of the library, sometimes one outside it, sometimes sessions),
    rows, acquisition, noise, measured tubes and the candidates to try."""
    rng = np.random.default_rng(seed)
    kind = "sweep" if rng.random() < 0.7 else "random"
    pool = list(IN_LIBRARY) + ["curved_length"] + (list(IN_LIBRARY_SEQUENCE) if kind == "sweep" else [])
    hidden = [str(e) for e in rng.choice(pool, size=int(rng.integers(0, 3)), replace=False)]
    if rng.random() < 0.15:
        hidden.append(str(rng.choice(OUTSIDE)))
    case = {"seed": seed, "kind": kind, "rows": int(rng.integers(40, 260)),
            "sigma_mm": float(rng.choice([0.05, 0.1, 0.2, 0.4])),
            "effects": {e: float(rng.choice([1.0, 1.0, 0.3, 2.0])) for e in hidden},
            "tubes": [0] if rng.random() < 0.4 else [0, 1, 2],
            "sessions": kind == "sweep" and rng.random() < 0.15,
            "moving": sorted(int(j) for j in rng.choice(6, size=int(rng.integers(1, 5)), replace=False))}
    others = [c for c in CAUSES if c not in {LIBRARY_CAUSE.get(e, e) for e in hidden}]
    causes = [LIBRARY_CAUSE.get(e, e) for e in hidden]
    case["candidates"] = sorted({*[c for c in causes if c in CAUSES],
                                 *[str(c) for c in rng.choice(others, size=3, replace=False)]})
    return case


def make_lab(case: dict):
    if case["sessions"]:
        differs = str(np.random.default_rng(case["seed"]).choice(["registration", "curvature"]))
        return sessions(case["rows"], seed=case["seed"], differs=differs, sigma_mm=case["sigma_mm"])
    return make(case["rows"], case["effects"], seed=case["seed"], sigma_mm=case["sigma_mm"],
                moving=tuple(case["moving"]), rows=case["kind"])


def check(case: dict, all_candidates: bool, tmp: Path) -> dict:
    """Diagnose one case; the properties that fail (empty: none)."""
    failures = []
    t0 = time.perf_counter()
    lab = make_lab(case)
    path = tmp / "fuzz.csv"
    lab.write_csv(path, tuple(case["tubes"]))
    candidates = tuple(CAUSES) if all_candidates else tuple(case["candidates"])
    try:
        diag = diagnose(read_measured(path, min_rows=10), options=DiagnoseOptions(candidates=candidates))
        j = diag.to_json()
        json.dumps(j, allow_nan=False)
    except Exception:       # noqa: BLE001  (the property under test: nothing raises)
        return {**case, "failures": ["raised: " + traceback.format_exc(limit=6)],
                "seconds": time.perf_counter() - t0}
    if j["cause"] not in VERDICTS and j["cause"].removesuffix(PER_SESSION) not in CAUSES:
        failures.append(f"cause {j['cause']!r} is not a verdict")
    if any(c.removesuffix(PER_SESSION) not in candidates for c in j["causes"]):
        failures.append(f"named {j['causes']} outside the candidates {candidates}")
    if j["causes"] and j["extended"]["mean_mm"] > 1.05 * j["nominal"]["mean_mm"]:
        failures.append(f"named {j['causes']} is worse than nominal on the held-out rows")
    hidden = {LIBRARY_CAUSE.get(e, e) for e in case["effects"]} & set(CAUSES)
    return {**case, "failures": failures, "named": j["causes"], "verdict": j["cause"],
            "exact": set(j["causes"]) == hidden if hidden <= set(candidates) else None,
            "explained": j["explained"], "seconds": time.perf_counter() - t0}


def seeds_of(text: str) -> list[int]:
    """``0-199`` or ``3,17,40``."""
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-199", help="draws, e.g. 0-199 or 3,17,40")
    ap.add_argument("--all-candidates", action="store_true", help="every cause (slower), not 3 + the hidden")
    ap.add_argument("--out", type=Path, help="write the records as JSON here")
    a = ap.parse_args()
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds_of(a.seeds):
            rec = check(draw(seed), a.all_candidates, Path(tmp))
            records.append(rec)
            state = "FAIL " + "; ".join(f.splitlines()[-1] for f in rec["failures"]) if rec["failures"] \
                else "ok"
            print(f"seed {seed:4d} {rec['kind']:6s} {rec['rows']:3d} rows {sorted(rec['effects'])} -> "
                  f"{rec.get('named')} {state} ({rec['seconds']:.0f} s)", flush=True)
    failed = [r for r in records if r["failures"]]
    exact = [r["exact"] for r in records if r.get("exact") is not None]
    print(f"{len(records)} draws, {len(failed)} failing: {[r['seed'] for r in failed]}; named the hidden set "
          f"exactly in {sum(exact)}/{len(exact)}")
    if a.out:
        a.out.write_text(json.dumps(records, indent=1, default=str))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
