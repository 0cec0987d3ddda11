"""Command line: ``python -m sim.capture SCENE --config a|b --out DIR [--set capture.FIELD=VALUE]
[--set views.FIELD=VALUE]``."""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import replace
from pathlib import Path

from artrecon import workers
from artrecon.errors import InputError
from artrecon.settings import parse_settings
from sim import views
from sim.capture.image_set import capture
from sim.capture.rig import CaptureError
from sim.capture_config import SET_EXAMPLE, SET_HELP, capture_settings

#: The first line of the help.
DESCRIPTION = "Eye-in-hand capture: the arm photographs the object from all sides."


def main(argv=None) -> int:
    """Command line: ``python -m sim.capture SCENE --config a|b --out DIR``."""
    p = argparse.ArgumentParser(prog="python -m sim.capture", description=DESCRIPTION)
    p.add_argument("scene", help="a bundled scene's name (pliers, truck, drawer) or an MJCF path")
    p.add_argument("--config", required=True, help="object configuration: a or b")
    p.add_argument("--out", required=True, type=Path, help="image set folder to create")
    p.add_argument("--views", type=int, default=views.DEFAULT_VIEWS_PER_RING,
                   help="views per full ring (default 36: neighbours 10 degrees apart)")
    p.add_argument("--seed", type=int, default=0, help="seed of ring phases and IK restarts")
    p.add_argument("--fill", type=float,
                   help="preferred share of the shorter image side the object's bounding sphere "
                        "fills (each ring may take 0.45-0.75 so that the arm reaches it; "
                        f"default {views.ViewPlanConfig().fill})")
    p.add_argument("--free-camera-fallback", action="store_true",
                   help="photograph views the arm cannot reach with a free camera")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out folder")
    p.add_argument("--plan-cache", type=Path, metavar="DIR",
                   help="reuse the view plan (rings and IK) of the same scene, configuration, "
                        "views and seed stored in DIR, and store new plans there")
    p.add_argument("--set", dest="settings", action="append", default=[],
                   metavar="capture.FIELD=VALUE|views.FIELD=VALUE", help=SET_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    problem = views.views_problem(args.views)
    if problem:
        p.error(problem)
    try:
        items = parse_settings(args.settings, SET_EXAMPLE)
        if args.fill is not None and "views.fill" in items:
            raise InputError("give the fill once: --fill or --set views.fill")
        settings = capture_settings(items)
        plan = replace(settings.views, views_per_ring=args.views, seed=args.seed,
                       **({} if args.fill is None else {"fill": args.fill}))
    except ValueError as e:  # InputError too
        p.error(str(e))
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        with workers.interrupts_remembered():
            res = capture(args.scene, args.config, args.out, view_plan=plan,
                          capture_config=settings.capture,
                          free_camera_fallback=args.free_camera_fallback,
                          overwrite=args.overwrite, progress=not args.quiet,
                          plan_cache=args.plan_cache)
    except (ValueError, FileNotFoundError, FileExistsError, PermissionError,
            CaptureError) as e:
        p.exit(2, f"error: {e}\n")
    except KeyboardInterrupt:
        p.exit(130, f"interrupted; {args.out} is as it was (run again to capture)\n")
    out = sys.stdout
    out.write(f"{res.n_captured}/{res.n_planned} views captured into {res.out_dir}\n")
    for u in res.unreachable:
        out.write(f"  unreachable: ring {u['ring']} azimuth {u['azimuth_deg']:.0f} deg: "
                  f"{u['reason']}\n")
    return 0

