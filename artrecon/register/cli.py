"""``artrecon register``: the registration stage's command (:mod:`artrecon.register.stage`).

Exit status 0 on success, 2 on bad input, 1 when a route fails or the two routes disagree, 130
when interrupted.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from artrecon.errors import ArtreconError, DegenerateError, InputError
from artrecon.files import read_json
from artrecon.register.stage import FreshImage, read_fresh_pose, read_matrix, register


def add_register_parser(sub) -> None:
    """The ``artrecon register`` subcommand."""
    r = sub.add_parser("register", help="put a reconstruction into the robot frame, in metres",
                       description=("Put a reconstruction into the robot frame, in metres: the "
                                    "SfM camera centres of configuration A against the arm's "
                                    "camera positions (--camera-poses), and/or a fresh image "
                                    "localised by PnP with the flange pose and the hand-eye "
                                    "transform (--image, --flange-pose)."))
    r.add_argument("model_dir", help="a folder written by 'artrecon reconstruct'")
    r.add_argument("--camera-poses", metavar="POSES.json",
                   help="route (a): the arm's camera poses of configuration A's images (a "
                        "capture's cameras.json)")
    r.add_argument("--image", action="append", default=[], metavar="IMG",
                   help="route (b): a fresh image of the object (repeatable; each with a "
                        "--flange-pose)")
    r.add_argument("--flange-pose", action="append", default=[], metavar="POSE.json",
                   help="the arm's flange (or camera) pose when the --image was taken: "
                        "{'T_world_flange': 4x4} or {'T_world_camera': 4x4}")
    r.add_argument("--hand-eye", metavar="HAND_EYE.json",
                   help="the camera's mount on the flange {'T_flange_camera': 4x4}; default: "
                        "calibrated from --hand-eye-poses (or --camera-poses)")
    r.add_argument("--hand-eye-poses", metavar="POSES.json",
                   help="a capture's poses with T_world_flange per image of A, to calibrate the "
                        "mount from (default: --camera-poses)")
    r.add_argument("--scale", type=float, help="metres per model unit, when known (e.g. a known "
                   "length); default: from the hand-eye calibration or route (a)")
    r.add_argument("--out", help="output folder (default MODEL_DIR/registration)")
    r.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    r.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    r.set_defaults(handler=run_command)


def run_command(args) -> int:
    """``artrecon register``: exit 0, 2 on bad input, 1 when a route fails or the two disagree."""
    try:
        if len(args.flange_pose) != len(args.image):
            raise InputError(f"give one --flange-pose per --image: {len(args.image)} image(s), "
                             f"{len(args.flange_pose)} pose file(s)")
        images = []
        for img, pose_file in zip(args.image, args.flange_pose, strict=True):
            p = read_fresh_pose(pose_file)
            images.append(FreshImage(Path(img), p.get("T_world_flange"),
                                     p.get("T_world_camera")))
        he = None
        if args.hand_eye:
            data = read_json(args.hand_eye)
            if not isinstance(data, dict) or "T_flange_camera" not in data:
                raise InputError(f"{args.hand_eye}: expected {{'T_flange_camera': 4x4}}")
            he = read_matrix(data["T_flange_camera"], f"{args.hand_eye}: T_flange_camera")
        if args.scale is not None and not (np.isfinite(args.scale) and args.scale > 0):
            raise InputError(f"--scale {args.scale}: give a positive number of metres per model "
                             "unit")
        res = register(args.model_dir, camera_poses=args.camera_poses, images=images,
                       hand_eye=he, hand_eye_poses=args.hand_eye_poses, scale=args.scale,
                       out_dir=args.out, overwrite=args.overwrite, seed=args.seed)
    except InputError as exc:
        print(f"artrecon register: error: {exc}", file=sys.stderr)
        return 2
    except (ArtreconError, DegenerateError) as exc:
        print(f"artrecon register: registration failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("artrecon register: interrupted; nothing was written", file=sys.stderr)
        return 130
    out = args.out or str(Path(args.model_dir) / "registration")
    print(f"wrote {out}: route {res.route}, scale {res.T_robot_model.scale:.6g} m per model unit")
    for name, r in res.routes.items():
        rep = r["report"]
        if name == "camera_centres":
            print(f"  camera centres: {rep['inliers']}/{rep['cameras']} cameras, rms "
                  f"{rep['rms_mm']:.2f} mm")
        else:
            for im in rep["images"]:
                print(f"  PnP {im['image']}: {im['inliers']}/{im['matches']} inliers, "
                      f"{im['reprojection_rms_px']:.2f} px; scale from {rep['scale_from']}")
    if res.agreement:
        c = res.agreement["comparison"]
        print(f"  routes agree: {c['translation_mm']:.2f} mm, {c['rotation_deg']:.3f} deg")
    return 0


