"""Capture timings: CPU per rendered image, part by part, and CPU per captured image set.

Usage: ``python benchmarks/bench_capture.py [SCENE ...] [--views N] [--frames F] [--config C]
[--no-capture]``. Prints, per scene:

- ``render``: the CPU (milliseconds of process time: the main thread and llvmpipe's rasteriser
  threads) of each part of one image of a capture, over F views of the capture plan with the
  arm at each view's joint angles (placed, not driven): moving the pyrender nodes to the MuJoCo
  state (``update``), the colour pass (``colour``), the flat pass that gives ground-truth depth
  and labels (``gt``: colour+depth+labels minus colour), turning them into the PNG arrays
  (``convert``) and encoding the three PNGs (``png``: colour, depth, labels). Each frame is
  rendered twice and the cheaper run kept (other processes on the machine inflate single runs).
- ``capture``: one full capture of configuration C (planning, arm motion in physics, rendering,
  writing): wall and CPU seconds, CPU per image, and the capture's own split when it reports one
  (``plan``/``move``/``png``/``render`` CPU seconds; the code before 2fe836a reports wall only).

Measured on this 2-core machine under a load average of 7-10 (other sessions' runs; CPU
seconds, wall times were 2-3x these), fe60ce6 (before) against 27f36b6 (after; pliers b at
2a7e8d7), 121 images per set, every image, depth and label PNG pixel-identical and
cameras.json, capture.json and ground_truth/poses.json byte-identical between the two:

    ms CPU per image   update  colour   gt  convert  png   | capture CPU s  plan  move  render  png
    pliers  before       0.7    176.5  17.5   1.6   36.1   | a 34.5, b 33.1
    pliers  after        0.7     81.6  20.9   1.7   20.3   | a 16.6 = 0.2 + 1.7 + 12.5 + 2.2
                                                           | b 17.8 = 0.5 + 3.5 + 11.8 + 2.1
    drawer  before       0.8    169.8  25.7   1.6   40.6   | a 89.8 (plan alone: 47.9)
    drawer  after        0.7     67.4  10.9   1.3   18.5   | a 61.9 = 38.2 + 9.0 + 12.3 + 2.4

(single runs; under this load the same code's CPU seconds vary by about 10% between runs. The
drawer's capture is now mostly its view plan: IK descents for 42 candidate rings of its lowest
ring.)

- ``--plan-cache``: each configuration captured three times, without a plan cache (``cold``),
  storing its view plan (``stored``) and from the stored plan (``cached``): CPU per step, the
  ratio cached / cold, and whether the three image sets are byte-identical.

The view plan cache (sim.capture.plan_views), measured at 0458c4f against 863fc30 (before), one
capture per process (``python -c "sim.capture.capture(...)"``), 121 images per set (drawer b:
124), load average 7-15 on the 2 cores (wall times 2-5x the CPU), CPU seconds of the capture
(``timings``; the process adds ~1.5 s of imports):

    CPU s             before (plan + move + render + png)   plan stored      plan cached
    pliers  a          10.6 = 0.2 + 0.8 + 8.1 + 1.4           11.1 (0.3)       10.5 (0.2)
    pliers  b          11.2 = 0.4 + 1.5 + 7.9 + 1.5           11.6 (0.4)       10.8 (0.2)
    drawer  a          29.9 = 16.1 + 4.1 + 8.2 + 1.6          31.1 (16.3)      13.7 (0.2)
    drawer  b          27.9 = 14.9 + 3.4 + 8.1 + 1.6          29.0 (15.9)      13.2 (0.2)
    truck   a          19.7 = 7.8 + 2.5 + 7.8 + 1.6           21.2 (9.0)       12.3 (0.2)
    truck   b          25.6 = 12.1 + 4.4 + 7.5 + 1.6          24.6 (11.6)      13.3 (0.2)

(in brackets: the plan's CPU; a cached plan's 0.2 s is hashing the compiled model and reading
plan.json). Every file of every set (images, depth, labels, cameras.json, capture.json,
poses.json) byte-identical across the three columns.

One JSON line per scene follows the table (``{"scene": ..., "render_ms": {...},
"capture": {...}}``). Timings only; nothing is asserted.

The script only uses the harness's public calls, so the same file measures older code: check
the old commit out beside this one and run this file with PYTHONPATH pointing there, e.g.
``git worktree add /tmp/before fe60ce6 && PYTHONPATH=/tmp/before python
benchmarks/bench_capture.py pliers drawer``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

import sim  # noqa: F401  (EGL before OpenGL)
from sim import capture, render, robot, views
from sim.camera import convert_camera_pose, mujoco_camera_intrinsics
from sim.capture import files as capture_files
from sim.scene import list_scenes, load_scene


def _cpu() -> float:
    return time.process_time()


def _commit() -> str:
    root = Path(sim.__file__).resolve().parent.parent
    try:
        return subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _write_pngs(out, tmp: Path) -> None:
    items = ((out.color, tmp / "c.png", "colour"),
             (capture_files.depth_png(out.depth), tmp / "d.png", "depth"),
             (capture_files.labels_png(out.labels), tmp / "l.png", "labels"))
    if not (hasattr(capture, "PNG_PARAMS") or hasattr(capture_files, "PNG_PARAMS")):
        # the writer before 2fe836a took (array, path)
        items = tuple(i[:2] for i in items)
    capture_files.write_pngs(items)


def bench_render(name: str, frames: int, config: str = "a") -> dict:
    """CPU milliseconds per image of each part (see the module docstring)."""
    sc = load_scene(name).with_joint_holds()
    model = sc.model
    data = sc.make_data(config)
    sc.hold(data, config)
    kin = robot.load_arm_kinematics(model)
    cam = kin.spec.prefix + kin.spec.camera
    cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, cam)
    K, (w, h) = mujoco_camera_intrinsics(model, cam)
    plan = views.plan_capture(model, data, kin, K, w, h, views.ViewPlanConfig(),
                              cell=views.KnownCell(sc.path))
    reach = plan.reachable
    chosen = [reach[int(i)] for i in np.linspace(0, len(reach) - 1, min(frames, len(reach)))]
    arm_root = int(model.jnt_bodyid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT,
                                                      kin.joint_names[0])])
    t0 = _cpu()
    r = render.MjRenderer(model, geom_labels=capture_files.geom_labels(model, sc, arm_root))
    build = _cpu() - t0
    qidx = robot.qpos_indices(model, kin)
    parts = {k: [] for k in ("update", "colour", "gt", "convert", "png")}
    with tempfile.TemporaryDirectory() as tmp:
        for k, view in enumerate(chosen):
            data.qpos[qidx] = view.q
            mujoco.mj_forward(model, data)
            T = convert_camera_pose(np.r_[np.c_[data.cam_xmat[cam_id].reshape(3, 3),
                                                data.cam_xpos[cam_id]], [[0, 0, 0, 1]]])
            if k == 0:  # warm-up: uploads meshes and textures, compiles shaders
                r.render(data, K, T, w, h, depth=True, labels=True)
            best = {key: np.inf for key in parts}
            for _ in range(2):
                t0 = _cpu()
                r.update(data)
                t1 = _cpu()
                r.render(None, K, T, w, h)
                t2 = _cpu()
                out = r.render(None, K, T, w, h, depth=True, labels=True)
                t3 = _cpu()
                capture_files.depth_png(out.depth)
                capture_files.labels_png(out.labels)
                t4 = _cpu()
                _write_pngs(out, Path(tmp))
                t5 = _cpu()
                for key, dt in (("update", t1 - t0), ("colour", t2 - t1),
                                ("gt", (t3 - t2) - (t2 - t1)), ("convert", t4 - t3),
                                ("png", t5 - t4)):
                    best[key] = min(best[key], dt)
            for key in parts:
                parts[key].append(best[key])
    ms = {key: 1e3 * float(np.mean(v)) for key, v in parts.items()}
    ms["total"] = sum(ms.values())
    print(f"{name:10s} render {w}x{h}, {len(chosen)} views, ms CPU per image: "
          + ", ".join(f"{k} {v:.1f}" for k, v in ms.items())
          + f" (scene build {build * 1e3:.0f} ms)")
    return {"frames": len(chosen), "width": w, "height": h, "build_ms": 1e3 * build, **ms}


def bench_capture(name: str, n_views: int, config: str = "a", keep: Path | None = None) -> dict:
    """One full capture: wall and CPU seconds, and its own split when it reports one. With
    ``keep``, the image set stays in ``keep/SCENE_CONFIG`` (to compare two versions' files)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "set" if keep is None else Path(keep) / f"{name}_{config}"
        t0, c0 = time.perf_counter(), _cpu()
        res = capture.capture(name, config, out, n_views=n_views, progress=False)
        wall, cpu = time.perf_counter() - t0, _cpu() - c0
        rings = json.loads((out / "capture.json").read_text())["rings"]
    t = res.timings
    n = max(1, res.n_captured)
    split = ""
    if "cpu_s" in t:
        split = (f" = plan {t['plan_cpu_s']:.1f} + move {t['move_cpu_s']:.1f} + render "
                 f"{t['render_cpu_s']:.1f} + png {t['png_cpu_s']:.1f}")
    print(f"{name:10s} capture {config}: {res.n_captured}/{res.n_planned} views, {cpu:.1f} s CPU"
          f"{split} ({1e3 * cpu / n:.0f} ms CPU per image); wall {wall:.1f} s (plan "
          f"{t['plan_s']:.1f}, move {t['move_s']:.1f}, render {t['render_s']:.1f}); FK vs MuJoCo "
          f"camera {res.max_fk_position_error:.1e} m, "
          f"{np.rad2deg(res.max_fk_rotation_error):.1e} deg")
    print(f"{name:10s} rings: " + ", ".join(
        f"{r['elevation_deg']:.1f} deg (wanted {r['desired_elevation_deg']:.0f}) at "
        f"{r['distance_m']:.3f} m, fill {r['fill']:.2f}, {r['candidates_tried']} tried"
        for r in rings))
    return {"config": config, "images": res.n_captured, "planned": res.n_planned,
            "wall_s": wall, "cpu_s": cpu, "cpu_ms_per_image": 1e3 * cpu / n,
            **{k: v for k, v in t.items() if k.endswith("_s")}}


def _tree_hash(folder: Path) -> str:
    """SHA-256 over the relative names and bytes of every file under ``folder``."""
    h = hashlib.sha256()
    for f in sorted(p for p in folder.rglob("*") if p.is_file()):
        h.update(str(f.relative_to(folder)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def bench_plan_cache(name: str, n_views: int, config: str = "a") -> dict:
    """Three captures of one configuration: without a plan cache (``cold``: as before the
    cache), with an empty one (``stored``: solves and stores the plan) and with the plan stored
    (``cached``). Prints the CPU of each step, the ratio cached / cold, and whether the three
    image sets are byte-identical."""
    if not hasattr(capture, "plan_views"):
        print(f"{name:10s} plan cache: not in this code")
        return {}
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        plans = Path(tmp) / "plans"
        for label, cache_dir in (("cold", None), ("stored", plans), ("cached", plans)):
            out = Path(tmp) / label
            t0, c0 = time.perf_counter(), _cpu()
            res = capture.capture(name, config, out, n_views=n_views, progress=False,
                                  plan_cache=cache_dir)
            t = res.timings
            rows[label] = {"wall_s": time.perf_counter() - t0, "cpu_s": _cpu() - c0,
                           "plan_cached": res.plan_cached, "hash": _tree_hash(out),
                           **{k: t[k] for k in ("plan_cpu_s", "move_cpu_s", "render_cpu_s",
                                                "png_cpu_s")}}
    same = len({r["hash"] for r in rows.values()}) == 1
    for label, r in rows.items():
        print(f"{name:10s} {config} {label:6s}: {r['cpu_s']:5.1f} s CPU = plan "
              f"{r['plan_cpu_s']:.1f} + move {r['move_cpu_s']:.1f} + render "
              f"{r['render_cpu_s']:.1f} + png {r['png_cpu_s']:.1f} (+ loading); wall "
              f"{r['wall_s']:.1f} s")
    ratio = rows["cached"]["cpu_s"] / rows["cold"]["cpu_s"]
    print(f"{name:10s} {config} cached / cold CPU {ratio:.2f}, plan CPU "
          f"{rows['cold']['plan_cpu_s']:.1f} -> {rows['cached']['plan_cpu_s']:.2f} s; files "
          f"{'byte-identical' if same else 'DIFFER'}")
    return {"config": config, "identical": same, "cached_over_cold_cpu": ratio,
            **{label: {k: v for k, v in r.items() if k != "hash"} for label, r in rows.items()}}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenes", nargs="*", help="scene names (default: all bundled scenes)")
    p.add_argument("--views", type=int, default=views.DEFAULT_VIEWS_PER_RING,
                   help="views per full ring of the capture")
    p.add_argument("--frames", type=int, default=12, help="views per render timing")
    p.add_argument("--config", nargs="+", default=["a"],
                   help="object configurations to capture (a, b or both)")
    p.add_argument("--no-capture", action="store_true", help="render timings only")
    p.add_argument("--no-render", action="store_true", help="no render timings")
    p.add_argument("--plan-cache", action="store_true",
                   help="capture each configuration three times: without a plan cache, storing "
                        "the plan, from the stored plan (CPU per step, ratio, file identity)")
    p.add_argument("--keep", type=Path, help="keep the captured sets in this folder")
    args = p.parse_args()
    print(f"# code at {_commit()}, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} "
          "CPUs (CPU seconds are what counts; wall time grows with the load)")
    for name in args.scenes or list_scenes():
        row = {"scene": name, "commit": _commit()}
        if not args.no_render:
            row["render_ms"] = bench_render(name, args.frames, args.config[0])
        for config in args.config:
            if args.plan_cache:
                row[f"plan_cache_{config}"] = bench_plan_cache(name, args.views, config)
            elif not args.no_capture:
                row[f"capture_{config}"] = bench_capture(name, args.views, config, args.keep)
        print(json.dumps(row))


if __name__ == "__main__":
    main()
