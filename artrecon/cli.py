"""Command line: ``artrecon reconstruct DIR_A DIR_B --out DIR [--from STAGE] [--to STAGE]``,
``artrecon register MODEL_DIR --camera-poses POSES.json [--image IMG --flange-pose POSE.json]``
and ``artrecon export MODEL --format mjcf|urdf|glb|ply --out PATH``.

Exit status 0 on success, 2 on bad input (also when nothing moved between the two image sets:
artrecon.errors.NoMotionError), 1 when a stage fails (also when the evidence for a joint
is too weak: artrecon.errors.WeakEvidenceError), 130 when interrupted; the message says what to
try, without a traceback.

``reconstruct --to STAGE`` stops after a stage (``--to configurations``: ``DIR/a``, ``DIR/b``;
``--to matches``: ``DIR/matches/`` too; then ``links``, ``joints``, ``refine``, each its folder
``DIR/<stage>/``) and prints the command that continues the run (``--from`` the next stage, the
same inputs and options). ``--from STAGE`` starts from the folders of an earlier run, checked,
and runs that stage and the later ones, with other settings of those stages if wanted (``--from
links``: the links and joints again with other segmentation, joint ... settings, on the same
matches; ``--from joints``: the joints on the same links; ``--from model``: only the model
assembled again); see artrecon.reconstruct.STAGES.
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
    r.add_argument("--out", required=True, help="output folder (model.json, matches.npz, "
                   "a/sparse/0, b/sparse/0, matches/, links/ (link_k.ply ...), joints/, "
                   "refine/ ...)")
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
                   "of a run stopped with --to); with --from: replace what the run writes (the "
                   "stage --from names, the later ones and the model), keep the stages before "
                   "it")
    stages = "{" + ",".join(STAGES) + "}"
    r.add_argument("--from", dest="from_stage", default="configurations", metavar=stages,
                   help="first stage to run: 'configurations' (default: from the images), or a "
                   "later one, starting from the folders an earlier run of the same images, "
                   "options and seed left for the stages before it (e.g. one stopped with --to "
                   "the stage before): 'matches' (OUT/a and OUT/b), 'links' (and "
                   "OUT/matches/), 'joints' (and OUT/links/), 'refine' (and OUT/joints/), "
                   "'model' (and OUT/refine/). The settings of the stages before it must be "
                   "those they were made with (sfm.*, dense.*, region.*; match.* and "
                   "segmentation.covariances; the links' segmentation.*, guided.*, assign.*, "
                   "freespace.*; the joints' joints.*, confidence.*; refine.*); those of the "
                   "stages it runs may differ. What a run starts from is checked, never "
                   "recomputed")
    r.add_argument("--to", dest="to_stage", default="model", metavar=stages,
                   help="last stage to run: 'model' (default), or stop after 'configurations' "
                   "(each configuration's SfM, dense points and object region: OUT/a, OUT/b), "
                   "'matches' (A x B: OUT/matches/), 'links' (OUT/links/), 'joints' "
                   "(OUT/joints/) or 'refine' (OUT/refine/)")
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
    if model is None:  # stopped after an earlier stage
        print(f"wrote {args.out} up to stage {args.to_stage!r} ("
              f"{STAGES[args.to_stage]}); continue with:\n  " + _continue_command(args))
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
