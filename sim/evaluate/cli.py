"""``python -m sim.evaluate``: the command line."""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from artrecon.errors import InputError
from artrecon.settings import parse_settings
from sim import perturb
from sim.capture_config import SET_EXAMPLE, SET_HELP, capture_settings
from sim.evaluate import record, report, sweep, sweep_report
from sim.evaluate.checks import check_run
from sim.evaluate.config import POSE_SOURCES, EvalConfig
from sim.evaluate.sweep import run
from sim.scene import Scene, SceneError, list_scenes, load_scene, physics_warnings
from sim.views import views_problem

#: Simulated time stepped per scene to look for MuJoCo warnings (the Menagerie check).
CHECK_SECONDS = 1.0


def validate(names: list[str]) -> int:
    """The ``--validate-only`` mode: compile, check, step physics, print the ground truth."""
    rows, bad = [], []
    for name in names:
        try:
            scene = load_scene(name)
            warnings = physics_warnings(scene, CHECK_SECONDS)
            if warnings:
                raise SceneError(f"{scene.path}: MuJoCo warnings in {CHECK_SECONDS:g} s of "
                                 f"physics: {warnings}; fix: look for interpenetrating "
                                 f"collision geoms, bad inertias or unstable gains")
        except SceneError as err:
            bad.append(name)
            print(f"BAD  {name}: {err}", file=sys.stderr)
            continue
        print(f"ok   {scene.name}: {len(scene.links)} links "
              f"({', '.join(li.name for li in scene.links)}), {len(scene.joints)} joints, "
              f"{scene.model.nbody} bodies, {scene.model.ngeom} geoms, no warnings in "
              f"{CHECK_SECONDS:g} s")
        rows += ground_truth_rows(scene)
    if rows:
        print()
        print(format_table(rows))
    if bad:
        print(f"\n{len(bad)} of {len(names)} scenes are bad: {', '.join(bad)}", file=sys.stderr)
        return 1
    return 0


def _fmt(v: np.ndarray, digits: int = 3) -> str:
    return "(" + ", ".join(f"{x:+.{digits}f}" for x in v) + ")"


def ground_truth_rows(scene: Scene) -> list[list[str]]:
    """Table rows (one per joint) of a scene's ground truth, human units (deg, mm)."""
    rows = []
    for j in scene.joints:
        unit, scale = ("deg", np.rad2deg(1.0)) if j.type == "revolute" else ("mm", 1000.0)
        rows.append([
            scene.name, j.name, j.type, f"{j.parent} -> {j.child}", _fmt(j.axis),
            _fmt(j.point), f"{j.value_a * scale:.1f} {unit}", f"{j.value_b * scale:.1f} {unit}",
            f"{j.motion * scale:+.1f} {unit}",
            f"[{j.range[0] * scale:.1f}, {j.range[1] * scale:.1f}] {unit}"])
    if not rows:
        rows.append([scene.name, "-", "rigid", "object", "-", "-", "-", "-", "-", "-"])
    return rows


def format_table(rows: list[list[str]]) -> str:
    """A plain-text table with a header."""
    header = ["scene", "joint", "type", "parent -> child", "axis (world, at A)",
              "point on axis (m)", "A", "B", "B - A", "range"]
    table = [header, *rows]
    widths = [max(len(r[i]) for r in table) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
             for r in table]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def parser() -> argparse.ArgumentParser:
    """The command line; its defaults are :class:`EvalConfig`'s (one default each)."""
    default = EvalConfig()
    p = argparse.ArgumentParser(
        prog="python -m sim.evaluate",
        description="Capture, reconstruct, register and manipulate each scene, score everything "
                    "against ground truth and write a report (results.json, results.md, PNGs).")
    p.add_argument("scenes", nargs="*",
                   help=f"bundled scene names or MJCF paths (default: all of {list_scenes()})")
    p.add_argument("--out", type=Path, default=Path("runs/eval"),
                   help="report folder; stage results are cached in OUT/cache (default runs/eval)")
    p.add_argument("--views", type=int, default=default.views,
                   help=f"views per full capture ring (default {default.views})")
    p.add_argument("--seed", type=int, default=default.seed,
                   help=f"seed of every stage (default {default.seed})")
    g = p.add_argument_group("sweeps (several seeds, runs in parallel)")
    g.add_argument("--seeds", type=_seeds, metavar="SEEDS",
                   help="run every scene once per seed: a range 0-4, a list 0,2,7 or both "
                        "0-2,9; the report then lists every run and per scene the median, "
                        "worst and spread over seeds (instead of --seed)")
    g.add_argument("--jobs", type=_positive, metavar="N",
                   help="runs at once: 1 (default) one after the other in this process; N > 1 "
                        "N worker processes on this machine; with --backend ray at most N in "
                        "flight (default: as many as the cluster takes)")
    g.add_argument("--backend", choices=sweep.BACKENDS, default="local",
                   help="where runs run: 'local' (this machine, default) or 'ray' (a Ray "
                        f"cluster; needs the extra: {sweep.RAY_EXTRA})")
    g.add_argument("--address", metavar="ADDR",
                   help="with --backend ray: an existing cluster (auto, HOST:PORT or "
                        "ray://HOST:10001); without it a local cluster is started for the sweep")
    g.add_argument("--resume", action="store_true",
                   help="skip the runs that OUT already holds finished (same settings, same "
                        "code); the others run, and so does a run whose run.json this code "
                        "does not read (another schema version: a warning says why)")
    p.add_argument("--poses", choices=POSE_SOURCES, default=default.poses,
                   help="camera poses: 'fk' the arm's forward kinematics, held fixed and checked "
                        "against the images; 'images' SfM from the images alone (the photo "
                        f"route); default {default.poses!r}")
    p.add_argument("--set", dest="settings", action="append", default=[],
                   metavar="capture.FIELD=VALUE|views.FIELD=VALUE", help=SET_HELP)
    p.add_argument("--no-manipulate", action="store_true", help="skip the manipulation")
    p.add_argument("--validate-only", action="store_true",
                   help="only compile and check the scenes and print their ground truth")
    p.add_argument("--report-only", action="store_true",
                   help="exploratory run: report the verdict but exit 0 even when a scene fails "
                        "a gate")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    perturb.add_arguments(p)
    return p


def _seeds(text: str) -> list[int]:
    try:
        return sweep.parse_seeds(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _positive(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return n


def sweep_from_args(args: argparse.Namespace) -> sweep.SweepConfig:
    """The run's :class:`~sim.evaluate.sweep.SweepConfig` (ValueError: a bad combination)."""
    return sweep.SweepConfig(jobs=args.jobs, backend=args.backend, address=args.address,
                             resume=args.resume, progress=not args.quiet)


def config_from_args(args: argparse.Namespace) -> EvalConfig:
    """The run's :class:`EvalConfig` from parsed arguments (ValueError: a bad value, an
    InputError for a bad ``--set``)."""
    return EvalConfig(views=args.views, seed=args.seed, poses=args.poses,
                      manipulate=not args.no_manipulate, progress=not args.quiet,
                      perturb=perturb.from_args(args),
                      capture_settings=capture_settings(parse_settings(args.settings,
                                                                       SET_EXAMPLE)))


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser_ = parser()
    args = parser_.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    names = args.scenes or list_scenes()
    if args.validate_only:
        return validate(names)
    if views_problem(args.views):
        parser_.error(views_problem(args.views))
    if args.seeds is not None and any(a == "--seed" or a.startswith("--seed=") for a in argv):
        parser_.error("give either --seed or --seeds, not both")
    if args.address and args.backend != "ray":
        parser_.error("--address is the address of a Ray cluster: add --backend ray")
    try:
        ev = config_from_args(args)
        cfg = sweep_from_args(args)
    except ValueError as err:
        parser_.error(str(err))
    try:  # before any capture: scenes that load and move, an --out off the scenes' files
        check_run(names, args.out)
    except (SceneError, InputError) as err:
        print(f"python -m sim.evaluate: error: {err}", file=sys.stderr)
        return 2
    if cfg.backend == "ray":
        try:
            import ray  # noqa: F401 (an optional extra: only to say it is missing)
        except ImportError:
            parser_.error(f"--backend ray needs Ray, which is not installed: {sweep.RAY_EXTRA}")
    seeds = args.seeds or [ev.seed]
    try:
        if len(seeds) == 1 and cfg.inline and not cfg.resume:
            results = run(names, replace(ev, seed=seeds[0]), args.out, argv)
        else:
            results = sweep.run_sweep(sweep.plan(names, ev, seeds), args.out, cfg, argv=argv)
    except sweep.SweepError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted: the runs finished so far are in {args.out / 'results.json'}; "
              "run the same command with --resume to go on (finished stages come from the "
              "cache)", file=sys.stderr)
        return 130
    rec = record.Results.from_json(results)  # what was written, as the record
    print()
    print(sweep_report.sweep_table(rec) if rec.layout == "sweep" else report.terminal_table(rec))
    print(f"\nreport: {args.out / 'results.json'}, {args.out / 'results.md'}")
    return finish(rec, report_only=args.report_only)


def finish(results: record.Results, report_only: bool = False) -> int:
    """Print the verdict's last line and return the exit status: 1 if any scene (any run of a
    sweep) failed a gate or raised an error (0 with ``report_only``, for exploratory runs)."""
    if results.layout == "sweep":
        return finish_sweep(results, report_only)
    scenes = results.scenes
    failed = {n: r for n, r in scenes.items() if r.error or not r.passed}
    if not failed:
        print(f"PASS: all {len(scenes)} scene(s) met every gate")
        return 0
    for n, r in failed.items():
        why = (r.error if r.error else
               "; ".join(f"{g.subject}: {g.gate}" for g in r.failed_gates or []))
        print(f"FAIL {n}: {why}", file=sys.stderr)
    names = ", ".join(f"{n} ({'error' if r.error else ', '.join(sorted({g.gate for g in r.failed_gates or []}))})"  # noqa: E501
                      for n, r in failed.items())
    print(f"FAIL: {len(failed)} of {len(scenes)} scene(s) missed a gate or failed: {names}"
          + (" (--report-only: exit status 0)" if report_only else ""))
    return 0 if report_only else 1


def finish_sweep(results: record.Results, report_only: bool = False) -> int:
    """:func:`finish` of a sweep: a line per run that did not pass (stderr), then the last line
    naming every such run (scene, seed) and its gates."""
    runs = results.runs
    failed = [r for r in runs if r.status != "passed"]
    if not failed:
        print(f"PASS: all {len(runs)} run(s) met every gate")
        return 0
    for r in failed:
        print(f"FAIL {sweep_report.run_name(r)}: {sweep_report.run_reason(r)}", file=sys.stderr)

    def gates_of(r):
        res = r.result
        if r.status == "not run":
            return "not run"
        if r.status == "died":
            return "worker died"
        if res is not None and res.error:
            return "error"
        return ", ".join(sorted({g.gate for g in (res and res.failed_gates) or []}))

    names = ", ".join(f"{sweep_report.run_name(r)} ({gates_of(r)})" for r in failed)
    print(f"FAIL: {len(failed)} of {len(runs)} run(s) missed a gate or failed: {names}"
          + (" (--report-only: exit status 0)" if report_only else ""))
    return 0 if report_only else 1
