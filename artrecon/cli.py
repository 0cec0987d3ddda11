"""Command line: ``artrecon reconstruct DIR_A DIR_B --out DIR [--from STAGE] [--to STAGE]``,
``artrecon register MODEL_DIR --camera-poses POSES.json [--image IMG --flange-pose POSE.json]``
and ``artrecon export MODEL --format mjcf|urdf|glb|ply --out PATH``.

Exit status 0 on success, 2 on bad input (also when nothing moved between the two image sets:
artrecon.errors.NoMotionError), 1 when a stage fails (also when the evidence for a joint
is too weak: artrecon.errors.WeakEvidenceError), 130 when interrupted; the message says what to
try, without a traceback.

``reconstruct --to configurations`` stops after the per-configuration stage (``DIR/a``,
``DIR/b``), ``--to matches`` after the matching (``DIR/matches/`` too); each prints the command
that continues the run (``--from`` the next stage, the same inputs and options). ``--from
model`` re-runs links and joints (with other segmentation, joint ... settings if wanted) on the
matches of an earlier run; see artrecon.reconstruct.STAGES.
"""

from __future__ import annotations

import argparse
import logging
import shlex
import sys

from artrecon.errors import ArtreconError, InputError, NoMotionError
from artrecon.export import add_export_parser
from artrecon.reconstruct import STAGES, reconstruct
from artrecon.register.cli import add_register_parser
from artrecon.settings import ReconstructConfig, parse_settings, with_settings


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="artrecon", description="Articulated models of objects from "
                                "two image sets, one per configuration.")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("reconstruct", help="reconstruct an articulated model from two image "
                       "folders")
    r.add_argument("dir_a", help="images of configuration A (a folder of photos, or a capture "
                   "folder with images/ and cameras.json)")
    r.add_argument("dir_b", help="images of configuration B")
    r.add_argument("--out", required=True, help="output folder (model.json, links/*.ply, "
                   "matches.npz, matches/, a/sparse/0, b/sparse/0 ...)")
    r.add_argument("--intrinsics", default=None, help="known pinhole intrinsics 'fx,fy,cx,cy' "
                   "(pixels) or a JSON file with 'K'; default: a folder's cameras.json, else "
                   "estimated by SfM")
    r.add_argument("--use-poses", action="store_true", help="use the camera poses in each "
                   "folder's cameras.json (the arm's forward kinematics): triangulate with the "
                   "poses fixed instead of searching for them (faster, metric)")
    r.add_argument("--set", dest="settings", action="append", default=[],
                   metavar="STAGE.FIELD=VALUE", help="change one reconstruction setting (a "
                   "field of artrecon.settings.ReconstructConfig, within its range in "
                   "artrecon.settings.RANGES; repeatable), e.g. dense.downsample=1: "
                   "full-resolution stereo for objects whose parts are only a few millimetres "
                   "thick (about 5x the dense stage's time), or sfm.matching=exhaustive")
    r.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    r.add_argument("--overwrite", action="store_true", help="replace an existing output folder "
                   "(only a previous result: a folder holding model.json or the configurations "
                   "of --to configurations or --to matches); with --from: replace what the "
                   "run writes (--from matches: the matches and model; --from model: the "
                   "model), keep the stages before it")
    stages = "{" + ",".join(STAGES) + "}"
    r.add_argument("--from", dest="from_stage", default="configurations", metavar=stages,
                   help="first stage to run: 'configurations' (default: from the images), "
                   "'matches' (start from OUT/a and OUT/b of an earlier run of the same images, "
                   "options and seed, e.g. one stopped with --to configurations) or 'model' "
                   "(start from OUT/a, OUT/b and OUT/matches/ of an earlier run of the same "
                   "images and seed, the same sfm.*, dense.*, region.*, match.* settings and "
                   "segmentation.covariances; the other settings (segmentation.*, joints.* "
                   "...) may differ). What a run starts from is "
                   "checked, never recomputed")
    r.add_argument("--to", dest="to_stage", default="model", metavar=stages,
                   help="last stage to run: 'model' (default), 'matches' (stop after matching "
                   "A x B: OUT/a, OUT/b, OUT/matches/) or 'configurations' (stop after each "
                   "configuration's SfM, dense points and object region: OUT/a, OUT/b)")
    r.add_argument("--quiet", action="store_true", help="no progress bars, warnings only")
    r.set_defaults(handler=_run_reconstruct)
    add_export_parser(sub)
    add_register_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``artrecon`` console script."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING if getattr(args, "quiet", False) else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    return args.handler(args)


def _run_reconstruct(args: argparse.Namespace) -> int:
    try:
        config = with_settings(ReconstructConfig(), parse_settings(args.settings))
        model = reconstruct(args.dir_a, args.dir_b, intrinsics=args.intrinsics,
                            poses=True if args.use_poses else None, out_dir=args.out,
                            seed=args.seed, config=config, overwrite=args.overwrite,
                            progress=not args.quiet, from_stage=args.from_stage,
                            to_stage=args.to_stage)
    except (InputError, NoMotionError) as exc:  # NoMotionError: A and B are one configuration
        print(f"artrecon: error: {exc}", file=sys.stderr)
        return 2
    except ArtreconError as exc:
        print(f"artrecon: reconstruction failed: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # disk full, no permission to write the output folder...
        print(f"artrecon: error: {exc}; nothing was written to {args.out}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"artrecon: interrupted; {args.out} is as it was (run again to start over)",
              file=sys.stderr)
        return 130
    if model is None:  # stopped after the configurations or the matches
        wrote = {"configurations": f"wrote {args.out}/a and {args.out}/b: the cameras, dense "
                 "points and object region of each configuration",
                 "matches": f"wrote {args.out}/a, {args.out}/b and {args.out}/matches: the "
                 "configurations and the matches across them"}[args.to_stage]
        print(f"{wrote} (stage {args.to_stage!r}); continue with:\n  "
              + _continue_command(args))
        return 0
    print(f"wrote {args.out}: {len(model.links)} links, {len(model.joints)} joints")
    cams = model.metadata.get("intrinsics") or {}
    if any(c.get("source") not in (None, "given") for c in cams.values()):
        print("  focal length " + ", ".join(
            f"{k.upper()} {c['focal_px']:.1f} px ({c['source']})" for k, c in sorted(cams.items())
            if "focal_px" in c))
    for j in model.joints:
        unit = "rad" if j.type == "revolute" else "model units"
        print(f"  {j.name}: {j.type}, axis {j.axis_direction.round(4).tolist()} through "
              f"{j.axis_point.round(4).tolist()}, moved {j.motion:.4f} {unit}")
        c = j.confidence
        if c:
            print(f"    confidence {c['score']:.2f}: matches {c['parent']['inliers']} + "
                  f"{c['child']['inliers']}, motion {c['motion']['snr']:.0f} x noise, axis "
                  f"spread {c['bootstrap']['axis_spread_deg']:.2f} deg")
    return 0


def _continue_command(args: argparse.Namespace) -> str:
    """The command that runs the rest of a run stopped with ``--to``: its inputs and options,
    ``--from`` the next stage."""
    names = list(STAGES)
    argv = ["artrecon", "reconstruct", args.dir_a, args.dir_b, "--out", args.out]
    if args.intrinsics is not None:
        argv += ["--intrinsics", args.intrinsics]
    if args.use_poses:
        argv.append("--use-poses")
    for item in args.settings:
        argv += ["--set", item]
    if args.seed != 0:
        argv += ["--seed", str(args.seed)]
    if args.quiet:
        argv.append("--quiet")
    return shlex.join(argv + ["--from", names[names.index(args.to_stage) + 1]])


if __name__ == "__main__":
    sys.exit(main())
