"""Capture timings: render time per frame and capture time per image set.

Usage: ``python benchmarks/bench_capture.py [SCENE ...] [--views N] [--frames F]``. Prints, per
scene: the time to build the pyrender scene, the time per rendered frame (colour only, and colour
plus depth and labels) at the wrist camera's resolution, and one full capture (planning, arm
motion, rendering, writing) with its reachable view count and the rings the planner chose
(distance, elevation, candidates tried). Timings only; nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

import sim  # noqa: F401  (EGL before OpenGL)
from sim import capture, render, robot, views
from sim.camera import mujoco_camera_intrinsics
from sim.scene import list_scenes, load_scene


def bench_render(name: str, frames: int) -> None:
    sc = load_scene(name)
    data = sc.make_data("a")
    kin = robot.load_arm_kinematics(sc.model)
    K, (w, h) = mujoco_camera_intrinsics(sc.model, kin.spec.prefix + kin.spec.camera)
    centre, radius = views.object_bounding_sphere(sc.model, data)
    dist = views.ring_distance(radius, K, w, h, 0.6)
    poses = [v.T_world_camera for v in views.plan_views(
        centre, dist, views.ViewPlanConfig(views_per_ring=frames, elevations_deg=(40.0,),
                                           top_elevations_deg=()))]
    t0 = time.perf_counter()
    r = render.MjRenderer(sc.model)
    t_build = time.perf_counter() - t0
    r.render(data, K, poses[0], w, h)  # warm-up: uploads meshes and textures
    t0 = time.perf_counter()
    for T in poses:
        r.render(data, K, T, w, h)
    t_col = (time.perf_counter() - t0) / len(poses)
    t0 = time.perf_counter()
    for T in poses:
        r.render(data, K, T, w, h, depth=True, labels=True)
    t_all = (time.perf_counter() - t0) / len(poses)
    print(f"{name:8s} render {w}x{h}: build {t_build * 1e3:7.1f} ms | colour "
          f"{t_col * 1e3:6.1f} ms/frame | colour+depth+labels {t_all * 1e3:6.1f} ms/frame "
          f"(ratio {t_all / t_col:.2f})")


def bench_capture(name: str, n_views: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = capture.capture(name, "a", Path(tmp) / "set", n_views=n_views, progress=False)
        total = time.perf_counter() - t0
        rings = json.loads((Path(tmp) / "set" / "capture.json").read_text())["rings"]
    t = res.timings
    print(f"{name:8s} capture {res.n_captured}/{res.n_planned} views: {total:6.1f} s per set "
          f"(plan {t['plan_s']:.1f} s, move {t['move_s']:.1f} s, render {t['render_s']:.1f} s, "
          f"{total / max(1, res.n_captured):.2f} s per image; FK vs MuJoCo camera "
          f"{res.max_fk_position_error:.1e} m, {np.rad2deg(res.max_fk_rotation_error):.1e} deg)")
    print(f"{name:8s} rings: " + ", ".join(
        f"{r['elevation_deg']:.1f} deg (wanted {r['desired_elevation_deg']:.0f}) at "
        f"{r['distance_m']:.3f} m, fill {r['fill']:.2f}, {r['candidates_tried']} tried"
        for r in rings) + f"; planning {t['plan_s'] / max(1, res.n_planned):.2f} s per view")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenes", nargs="*", help="scene names (default: all bundled scenes)")
    p.add_argument("--views", type=int, default=36, help="views per full ring of the capture")
    p.add_argument("--frames", type=int, default=12, help="frames per render timing")
    args = p.parse_args()
    for name in args.scenes or list_scenes():
        bench_render(name, args.frames)
        bench_capture(name, args.views)


if __name__ == "__main__":
    main()
