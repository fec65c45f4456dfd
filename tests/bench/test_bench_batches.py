"""`bench plan` runs its runs in batches that share one scene and backend (loaded once per batch)."""

from __future__ import annotations

from ctrplan.bench import planning as planning_bench


def test_batches_keep_one_scene_and_backend_and_cover_every_run_once():
    specs = planning_bench.make_specs([("a.yaml", 5.0), ("b.yaml", 5.0)], ["pinn", "cosserat"],
                                      ["rrtconnect", "rrt"], 13, 0)
    for workers in (1, 2, 5):
        jobs = planning_bench.batches(specs, workers)
        flat = [s for job in jobs for s in job]
        assert len(flat) == len(specs) and set(flat) == set(specs)  # every run once
        for job in jobs:
            assert len({(s.scene, s.backend) for s in job}) == 1
            assert len(job) <= planning_bench.BATCH_RUNS
        # 26 runs per scene and backend: at most BATCH_RUNS per job, else an even share of the workers
        size = min(planning_bench.BATCH_RUNS, -(-26 // workers))
        assert len(jobs) == 4 * -(-26 // size)
