#!/usr/bin/env python3
"""Time the new-user walk of issue 41 step by step, as a user types it: one's own label volume (NIfTI and
3D Slicer `.seg.nrrd`), one's own robot, the robot placed at the nostril, margins on the carotids, a plan,
a roadmap and a trajectory at a fixed rate in actuator units.

    flock /work/heavy.lock python scripts/time_patient_walk.py OUT_DIR [--roadmap-time 2m]

Each step is one `ctrplan` command (or `scripts/patient_walk.py`, which makes the inputs) run as a
subprocess from OUT_DIR; its wall time, exit code and the line that tells its outcome are printed,
and the table goes to OUT_DIR/walk_times.md (docs/benchmarks.md "The new-user walk" quotes it). Stops at
the first step that fails. `scene place` verifies with the exact model; `plan` and the roadmap use the
default backend, the PINN: a robot of one's own has one when its tubes are those a shipped model was
trained for (as here: the paper's tubes, other limits and actuators), else after `ctrplan train`.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NOSTRIL = "-4,9,0"  # the right nostril of the skull-base anatomy (scene frame, mm)


def steps(roadmap_time: str) -> list[tuple[str, str, str]]:
    """(what, command, the word of the output line that tells the outcome) of the walk, in order;
    commands run in OUT_DIR."""
    template = ROOT / "scenes" / "skullbase.yaml"
    ctr = f"{shlex.quote(sys.executable)} -m ctrplan"
    return [
        ("make the label volume (NIfTI + .seg.nrrd), names, robot", f"{shlex.quote(sys.executable)} "
         f"{ROOT / 'scripts' / 'patient_walk.py'} .", "voxels of"),
        ("scene from NIfTI labels (names.yaml, 2 mm carotid margins)",
         f"{ctr} scene from-labels labels.nii.gz --names names.yaml --template {template} "
         f"--out nii/scene.yaml", "wrote"),
        ("scene from the Slicer .seg.nrrd (segment names read, margins.yaml)",
         f"{ctr} scene from-labels labels.seg.nrrd --names margins.yaml --template {template} "
         f"--out seg/scene.yaml", "wrote"),
        ("scene check with the own robot", f"{ctr} scene check nii/scene.yaml --robot robot.yaml", "usable"),
        ("scene place at the right nostril",
         f"{ctr} scene place nii/scene.yaml --entry={NOSTRIL} --robot robot.yaml", "placed in"),
        ("scene check of the placed scene", f"{ctr} scene check nii/scene.yaml", "usable"),
        ("plan (default backend: the PINN of the paper's tubes) with trajectory.csv at 100 Hz",
         f"{ctr} plan nii/scene.yaml --out plan --rate 100", "exact model"),
        ("roadmap build (own robot, default backend)",
         f"{ctr} roadmap build nii/scene.yaml --robot robot.yaml --time-limit {roadmap_time} --out roadmap",
         "target:"),
        ("roadmap query",
         f"{ctr} plan nii/scene.yaml --roadmap roadmap --out plan_roadmap", "solved"),
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--roadmap-time", default="2m")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT), COLUMNS="200")
    rows, total = [], 0.0
    for what, command, word in steps(args.roadmap_time):
        t0 = time.perf_counter()
        done = subprocess.run(command, shell=True, cwd=args.out, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        total += wall
        lines = [line.strip(" │") for line in (done.stdout + done.stderr).splitlines() if line.strip()]
        told = [line for line in lines if word in line] if not done.returncode else []
        last = " ".join((told or lines or [""])[-1].split())
        rows.append((what, wall, done.returncode, last))
        print(f"{wall:7.1f} s  rc {done.returncode}  {what}: {last}", flush=True)
        (args.out / f"step{len(rows)}.log").write_text(f"$ {command}\n{done.stdout}\n{done.stderr}")
        if done.returncode:
            break
    table = ["| step | wall (s) | exit | outcome |", "|---|---:|---:|---|"]
    table += [f"| {w} | {t:.1f} | {rc} | {last.replace('|', '/')[:140]} |" for w, t, rc, last in rows]
    table.append(f"| **total** | **{total:.1f}** | | |")
    (args.out / "walk_times.md").write_text("\n".join(table) + "\n")
    print("\n".join(table))
    return max(rc for _, _, rc, _ in rows)


if __name__ == "__main__":
    sys.exit(main())
