"""``python -m sim.manipulate``: grasp a scene's object and move it along a joint, with a picture.

``python -m sim.manipulate SCENE --model MODEL.json [--joint NAME] [--angle DEG | --distance M]
--out DIR`` plans from a registered model (robot frame, metres: ``artrecon register``'s
``model.json``) and moves its joint (default: the model's first joint) by the model's own motion
A -> B; without ``--model`` it follows the scene's ground-truth joint (a demonstration) by the
scene's own A -> B motion. Writes ``manipulation.json`` and ``strip.png`` (snapshots of the
approach and the motion).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
from PIL import Image

from artrecon.model import ArticulatedModel
from sim import render, robot
from sim.manipulate import (
    ManipulationError,
    ManipulationResult,
    build_world,
    joint_estimate_from_model,
    joint_estimate_from_scene,
    manipulate,
)
from sim.manipulate.world import World
from sim.scene import load_scene

log = logging.getLogger(__name__)

#: Scene camera of the image strip: looks at STRIP_TARGET from STRIP_DISTANCE, STRIP_ELEVATION up,
#: from the side (90 degrees in azimuth from the grasp point), so neither the arm nor the object
#: hides the gripper; fixed for the whole strip.
STRIP_TARGET = np.array([0.0, 0.0, 0.55])
STRIP_DISTANCE = 1.0
STRIP_ELEVATION = np.deg2rad(30.0)
STRIP_FRAMES = 6


def render_strip(world: World, result: ManipulationResult, path: Path,
                 n: int = STRIP_FRAMES) -> Path:
    """Render ``n`` snapshots of the approach and motion side by side into one PNG."""
    frames = [f for f in result.frames if f[1] != "travel"] or result.frames
    if not frames:
        raise ValueError("no frames recorded: run manipulate with record_every")
    g = np.asarray(result.grasp_point)
    az = np.arctan2(g[1], g[0]) + np.pi / 2
    eye = STRIP_TARGET + STRIP_DISTANCE * np.array([
        np.cos(STRIP_ELEVATION) * np.cos(az), np.cos(STRIP_ELEVATION) * np.sin(az),
        np.sin(STRIP_ELEVATION)])
    K = np.array([[554.26, 0, 319.5], [0, 554.26, 239.5], [0, 0, 1]])
    T = robot.look_at_pose(eye, STRIP_TARGET)
    r = render.MjRenderer(world.model)
    data = mujoco.MjData(world.model)
    picks = np.linspace(0, len(frames) - 1, n).round().astype(int)
    tiles = []
    for i in picks:
        data.qpos[:] = frames[i][2]
        mujoco.mj_forward(world.model, data)
        tiles.append(r.render(data, K, T, 640, 480).color)
    Image.fromarray(np.concatenate(tiles, axis=1)).save(path)
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim.manipulate",
                                description=__doc__.split("\n\n")[0].strip("`"))
    p.add_argument("scene", help="bundled scene name or MJCF path")
    p.add_argument("--model", type=Path, help="registered ArticulatedModel JSON (robot frame, m; "
                   "artrecon register's model.json): plan from it. Default: the scene's "
                   "ground-truth joint (a demonstration)")
    p.add_argument("--joint", help="the model's joint (name) or, without --model, the scene's "
                   "joint to move (default: the model's first joint / the scene's first joint "
                   "that moves between A and B)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--angle", type=float, help="requested rotation (deg) of a revolute joint "
                   "(default: the A -> B motion)")
    g.add_argument("--distance", type=float, help="requested translation (m) of a prismatic "
                   "joint (default: the A -> B motion)")
    p.add_argument("--visible", action="store_true", help="prefer a grasp point the camera sees")
    p.add_argument("--tilt", type=float, default=0.0,
                   help="tilt the followed axis by this many degrees (a deliberately wrong axis)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        scene = load_scene(args.scene)
        registered, model_joint = None, None
        if args.model is not None:
            registered = ArticulatedModel.load(args.model)
            names = [j.name for j in registered.joints]
            if args.joint is not None and args.joint not in names:
                p.error(f"--joint {args.joint!r}: the model's joints are {names}")
            model_joint = names.index(args.joint) if args.joint is not None else 0
            est = joint_estimate_from_model(registered, model_joint)
            default_amount = float(registered.joints[model_joint].motion)
        else:
            est = joint_estimate_from_scene(scene, args.joint)
            default_amount = float(scene.joint(est.name).motion)
            log.warning("no --model: following the GROUND-TRUTH axis of joint %r (a "
                        "demonstration)", est.name)
        if args.tilt:
            est = est.tilted(args.tilt)
        if est.type == "revolute" and args.distance is not None:
            p.error("the joint is revolute: give --angle")
        if est.type == "prismatic" and args.angle is not None:
            p.error("the joint is prismatic: give --distance")
        amount = (np.deg2rad(args.angle) if args.angle is not None else
                  args.distance if args.distance is not None else default_amount)
        world = build_world(scene)
        res = manipulate(scene, est, amount, registered=registered, model_joint=model_joint,
                         joint=None if registered is not None else est.name,
                         prefer_hidden=not args.visible, record_every=0.05, seed=args.seed,
                         world=world)
    except (ManipulationError, ValueError, OSError) as err:
        log.error("%s", err)
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"interrupted; nothing was written to {args.out}\n")
        return 130
    args.out.mkdir(parents=True, exist_ok=True)
    out = res.to_dict()
    out["axis_source_note"] = ("ground-truth axis from the scene file" if args.model is None
                               else f"estimated axis from {args.model}")
    out["created"] = time.strftime("%Y-%m-%dT%H:%M:%S")
    (args.out / "manipulation.json").write_text(json.dumps(out, indent=2) + "\n")
    strip = render_strip(world, res, args.out / "strip.png")
    moved = {k: round(res.displacement(k), 5) for k in res.joints_after
             if abs(res.displacement(k)) > 1e-4}
    summary = {"scene": res.scene, "requested": amount, "object joints moved": moved,
               "peak_force_n": res.peak_force, "grasp_lost": res.grasp_lost,
               "grasp_hidden": res.grasp_hidden, "grasp_visibility": res.grasp_visibility}
    sys.stdout.write(json.dumps(summary, indent=2) + "\n")
    sys.stdout.write(f"wrote {args.out / 'manipulation.json'} and {strip}\n")
    return 0
