"""Wall time of one sweep run one after the other (``--jobs 1``) and on two worker processes
(``--jobs 2``), optionally on a local Ray cluster too, and whether the figures are the same
(issue 26). Figures only, no asserts (speed is never asserted by a test)::

    nice -n 15 python benchmarks/bench_sweep.py [--scene pliers [truck ...]] [--seeds 0-1]
                                                [--views 12] [--manipulate] [--ray]
                                                [--out runs/bench_sweep]

Each configuration runs the same sweep (``python -m sim.evaluate SCENE ... --seeds S --views V
--no-manipulate``) into a fresh folder of its own (``OUT/<time>/jobs1``, ``jobs2``, ``ray``: a
fresh stage cache each, so every run computes everything). Prints the wall time of each, the
ratio, the load average of the machine before and after (others' work slows both), and whether
every run's figures equal those of ``--jobs 1`` (the runs are deterministic per seed).
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: Keys of a run's result that tell when and where it ran, not what it measured.
VOLATILE = {"wall_s", "timings_s", "reconstruct_timings_s", "cached_stages", "attempts",
            "traceback", "build_s", "timings", "date"}


def stable(obj):
    """``obj`` without :data:`VOLATILE` keys and with the run folders' paths cut off (anything
    under a run's own folder)."""
    if isinstance(obj, dict):
        return {k: stable(v) for k, v in obj.items() if k not in VOLATILE}
    if isinstance(obj, list):
        return [stable(v) for v in obj]
    if isinstance(obj, str) and "/cache/" in obj:
        return obj[obj.index("/cache/"):]
    return obj


def _cpu_s() -> float:
    """User + system CPU seconds of this process and its finished children (the workers)."""
    import resource

    return sum(resource.getrusage(who).ru_utime + resource.getrusage(who).ru_stime
               for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))


def main(argv=None) -> int:
    from sim.evaluate import EvalConfig, sweep

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scene", nargs="+", default=["pliers"], help="one or more scenes")
    p.add_argument("--seeds", type=sweep.parse_seeds, default=[0, 1])
    p.add_argument("--views", type=int, default=12)
    p.add_argument("--manipulate", action="store_true")
    p.add_argument("--ray", action="store_true", help="also on a local Ray cluster (2 CPUs)")
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "bench_sweep")
    args = p.parse_args(argv)
    out = args.out / datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    ev = EvalConfig(views=args.views, manipulate=args.manipulate, progress=False)
    specs = sweep.plan(args.scene, ev, args.seeds)
    configs = [("jobs1", sweep.SweepConfig(jobs=1, progress=False)),
               ("jobs2", sweep.SweepConfig(jobs=2, progress=False))]
    if args.ray:
        configs.append(("ray", sweep.SweepConfig(backend="ray", jobs=2, progress=False)))
    print(f"{len(specs)} runs ({', '.join(args.scene)}, seeds {args.seeds}, {args.views} views "
          f"per ring, {'with' if args.manipulate else 'no'} manipulation) on "
          f"{os.cpu_count()} cores; out {out}", flush=True)
    walls, figures = {}, {}
    for name, cfg in configs:
        load0 = os.getloadavg()
        cpu0 = _cpu_s()
        t0 = time.perf_counter()
        res = sweep.run_sweep(specs, out / name, cfg, layout="sweep",
                              command=f"bench_sweep {name}")
        walls[name] = time.perf_counter() - t0
        cpu = _cpu_s() - cpu0
        load1 = os.getloadavg()
        figures[name] = [stable(r["result"]) for r in res["runs"]]
        status = ", ".join(f"{r['id']} {r['status']}" for r in res["runs"])
        # Ray's workers are the raylet's children, not this process's: their CPU is not counted
        busy = ("" if name == "ray" else
                f"; {cpu:.0f} CPU s in this process and its workers ({cpu / walls[name]:.2f} "
                "cores busy on average)")
        print(f"{name}: {walls[name]:.0f} s wall{busy}; load average (1 min) {load0[0]:.1f} "
              f"before, {load1[0]:.1f} after; {status}", flush=True)
    for name in walls:
        if name != "jobs1":
            same = figures[name] == figures["jobs1"]
            print(f"{name} / jobs1 wall time: {walls[name] / walls['jobs1']:.2f}; figures "
                  f"{'the same as' if same else 'DIFFERENT from'} jobs1")
    return 0


if __name__ == "__main__":
    sys.exit(main())
