"""One image set: the arm photographs the object from all sides (:func:`capture`).

The views lie on rings around the object, each ring's distance and elevation chosen so that the
arm reaches every view of it without a collision (:func:`sim.views.plan_capture`); the arm reaches
each by inverse kinematics and MuJoCo moves it there with its position servos (physics, joint-space
interpolation), then the image is rendered with pyrender (:mod:`sim.render`) at the wrist camera's
true pose. The object is at rest while it is photographed: its joints are held at the
configuration's values by stiff joint equalities (:meth:`sim.scene.Scene.with_joint_holds`; joint
friction alone lets a loaded hinge creep over the minutes of a capture), and every physics step
is checked for contacts of the arm, so that an arm that touches the object (or the table, or
itself) is an error, not a hold that quietly absorbs it. The set is written to a temporary folder
beside DIR and renamed, so DIR is whole or absent.
"""

from __future__ import annotations

import json
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
from tqdm import tqdm

from artrecon import workers
from artrecon.files import publish_dir, work_dir
from artrecon.geometry import rotation_angle
from sim import render, robot, views
from sim.capture.arm import Arm
from sim.capture.files import (
    DEPTH_PNG_SCALE,
    LABEL_PNG_ARM,
    LABEL_PNG_BACKGROUND,
    LABEL_PNG_STAGE,
    as_list,
    check_out_dir,
    depth_png,
    geom_labels,
    labels_png,
    scene_inputs,
    write_pngs,
)
from sim.capture.plan import plan_views
from sim.capture.rig import CONFIGS, CaptureError, Rig, make_rig, true_camera_pose
from sim.capture_config import CaptureConfig
from sim.scene import Scene

log = logging.getLogger(__name__)

#: Fewest images a set may have: fewer cannot give a reconstruction from all sides.
MIN_CAPTURED_VIEWS = 8


@dataclass
class CaptureResult:
    """What :func:`capture` wrote."""

    out_dir: Path
    """the image set folder"""
    n_planned: int
    """views planned"""
    n_captured: int
    """images written"""
    unreachable: list[dict] = field(default_factory=list)
    """views the arm could not reach: ring, azimuth/elevation (deg), reason"""
    free_camera: list[int] = field(default_factory=list)
    """image indices taken by a free camera (only with ``free_camera_fallback``)"""
    max_fk_position_error: float = 0.0
    """largest distance (m) between the FK camera pose and MuJoCo's camera"""
    max_fk_rotation_error: float = 0.0
    """largest angle (rad) between them"""
    plan_cached: bool = False
    """the view plan was read from the plan cache (no IK was solved)"""
    timings: dict = field(default_factory=dict)
    """seconds spent planning, moving, rendering (wall, ``*_s``) and CPU seconds (``*_cpu_s``,
    ``cpu_s`` the whole capture's, all threads); not written to disk"""


def capture(scene, config: str, out_dir, *, n_views: int = views.DEFAULT_VIEWS_PER_RING,
            elevations_deg: tuple[float, ...] = (20.0, 40.0, 60.0),
            top_elevations_deg: tuple[float, ...] = (70.0,), fill: float = 0.6,
            fill_range: tuple[float, float] = (0.45, 0.75),
            max_elevation_shift_deg: float = 10.0, seed: int = 0,
            free_camera_fallback: bool = False, overwrite: bool = False,
            progress: bool = True, plan_cache=None,
            view_plan: views.ViewPlanConfig | None = None,
            capture_config: CaptureConfig = CaptureConfig()) -> CaptureResult:
    """Capture one image set of a scene in one configuration of its object.

    Parameters
    ----------
    scene : str, path or sim.scene.Scene
        A bundled scene's name (``"pliers"``), an MJCF path, or a loaded scene.
    config : {"a", "b"}
        Which configuration of the object to photograph.
    out_dir : path
        Folder to create (its parent must exist and be writable).
    n_views : int
        Views per full ring (36 keeps neighbours 10 degrees apart, as the method needs); rings near
        the top get proportionally fewer.
    elevations_deg, top_elevations_deg, fill, fill_range, max_elevation_shift_deg
        Ring layout, see :class:`sim.views.ViewPlanConfig`: desired elevations, the preferred
        share of the image the object fills and the band each ring's distance may take, and how
        far a ring's elevation may move when no distance in the band lets the arm reach all of it.
    seed : int
        Seeds each ring's first azimuth and the IK restarts. Same arguments, same files.
    free_camera_fallback : bool
        Photograph views the arm cannot reach with a free camera (pose unknown to the robot:
        ``T_world_camera`` is null in cameras.json). Off by default: those views are reported.
    overwrite : bool
        Replace an existing ``out_dir``.
    progress : bool
        Show a tqdm progress bar.
    plan_cache : path, optional
        Folder of cached view plans (:func:`plan_views`): the plan of these same inputs is read
        from there instead of solved, and a new one is stored there. The files written are the
        same either way.
    view_plan : sim.views.ViewPlanConfig, optional
        The whole view plan's settings, the ring layout and the planner's tunables (IK
        restarts, clearance, the search's steps), instead of the layout arguments above (which
        must then be left at their defaults); by default those arguments with the default
        tunables.
    capture_config : CaptureConfig
        The arm's motion between views and how far the object may drift.

    Returns
    -------
    CaptureResult
    """
    if config not in CONFIGS:
        raise ValueError(f"unknown configuration {config!r}; choose one of {CONFIGS}")
    plan_cfg = views.ViewPlanConfig(views_per_ring=n_views, elevations_deg=tuple(elevations_deg),
                                    top_elevations_deg=tuple(top_elevations_deg), fill=fill,
                                    fill_range=tuple(fill_range),
                                    max_elevation_shift_deg=max_elevation_shift_deg, seed=seed)
    if view_plan is not None:
        if plan_cfg != views.ViewPlanConfig():
            raise ValueError("give the ring layout either as arguments (n_views, elevations_deg, "
                             "top_elevations_deg, fill, fill_range, max_elevation_shift_deg, "
                             "seed) or in view_plan, not both")
        plan_cfg = view_plan
    out_dir = check_out_dir(Path(out_dir), overwrite, scene_inputs(scene))
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    rig = make_rig(scene, config)
    sc, model, data, kin = rig.scene, rig.model, rig.data, rig.kin
    K, width, height = rig.K, rig.width, rig.height
    joints_config = sc.configuration(config)
    # the object's true bounding sphere: ground_truth/poses.json only, to score the survey's
    true_sphere = views.object_bounding_sphere(model, data)

    expected = sum(n for _, n in views.ring_sizes(plan_cfg))
    bar = tqdm(total=2 * expected, desc=f"capture {sc.name}/{config}", unit="view",
               disable=not progress)
    plan, plan_cached = plan_views(model, data, kin, K, width, height, plan_cfg,
                                   cell=views.KnownCell(sc.path), cache_dir=plan_cache,
                                   stage=f"plan_{config}", progress=bar)
    t_plan = time.perf_counter()
    # the process's CPU, not the main thread's: the plan's survey renders on the rasteriser's
    # threads (barrett_hand: 5.7 CPU s, 2.2 of them on the main thread); no PNG writer yet
    plan_cpu = time.process_time() - cpu_start
    log.info("%s config %s: %d views on %d rings around the object (radius %.3f m): %s", sc.name,
             config, len(plan.views), len(plan.rings), plan.radius,
             ", ".join(f"{np.rad2deg(r.elevation):.1f} deg at {r.distance:.3f} m"
                       for r in plan.rings))
    reachable = plan.reachable
    to_take = [v for v in plan.views if v.reachable or free_camera_fallback]
    bar.total = len(plan.views) + len(to_take)
    bar.n = len(plan.views)
    bar.refresh()
    if len(to_take) < MIN_CAPTURED_VIEWS:
        bar.close()
        raise CaptureError(
            f"only {len(reachable)} of {len(plan.views)} planned views of {sc.name!r} are "
            f"reachable (need {MIN_CAPTURED_VIEWS}); use more views per ring (--views), other "
            f"elevations, or --free-camera-fallback. First reasons: "
            + "; ".join(f"view {v.index}: {v.reason}" for v in plan.unreachable[:3]))

    arm_root = int(model.jnt_bodyid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT,
                                                      kin.joint_names[0])])
    renderer = render.MjRenderer(model, geom_labels=geom_labels(model, sc, arm_root))
    arm = Arm(model, data, kin, capture_config)
    if reachable:
        arm.place(reachable[0].q)

    # the work folder goes when the capture ends unpublished, after the PNG writer has stopped
    with work_dir(out_dir) as tmp:
        # PNGs are compressed and written in a background thread (zlib releases the GIL) while the
        # arm moves to the next view
        writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="capture-png")
        writes = []
        try:
            for sub in ("images", "ground_truth/depth", "ground_truth/labels"):
                (tmp / sub).mkdir(parents=True)
            cam_images, gt_images, free = [], [], []
            t_move = t_render = move_cpu = png_cpu = 0.0
            max_dp = max_dr = 0.0
            for i, view in enumerate(to_take):
                workers.raise_if_interrupted()  # a Ctrl-C that a library swallowed
                name = f"{i:03d}.png"
                t0, c0 = time.perf_counter(), time.thread_time()
                path_hits: list[str] = []
                if view.reachable:
                    path_hits = arm.move(view.q)
                    if path_hits:
                        raise CaptureError(
                            f"the arm touched {', '.join(path_hits)} on its way to view {i} of "
                            f"{sc.name!r} (ring {view.ring}, azimuth "
                            f"{np.rad2deg(view.azimuth):.0f} deg): the planned views are "
                            "collision-free but the straight joint-space move between them is not; "
                            "try other elevations or --views")
                joints_now = sc.joint_values(data)
                drift = max((abs(joints_now[k] - joints_config[k]) for k in joints_now),
                            default=0.0)
                if drift > capture_config.object_drift_tol:
                    raise CaptureError(
                        f"the arm moved the object of {sc.name!r} by {drift:.2e} (rad or m) while "
                        f"reaching view {i} (contacts: {', '.join(path_hits) or 'none seen'}); the "
                        "scene or the view plan lets the arm hit the object")
                T_true = true_camera_pose(data, rig.cam_id)
                if view.reachable:
                    q = arm.measured_q()
                    T_fk = kin.camera_pose(q)
                    dp = float(np.linalg.norm(T_fk[:3, 3] - T_true[:3, 3]))
                    dr = rotation_angle(T_fk[:3, :3].T @ T_true[:3, :3])
                    max_dp, max_dr = max(max_dp, dp), max(max_dr, dr)
                    T_render = T_true
                else:
                    q, T_fk, dp, dr = None, None, None, None
                    T_render = view.T_world_camera
                    free.append(i)
                t1 = time.perf_counter()
                move_cpu += time.thread_time() - c0
                out = renderer.render(data, K, T_render, width, height, depth=True, labels=True)
                t2 = time.perf_counter()
                t_move += t1 - t0
                t_render += t2 - t1
                writes.append(writer.submit(write_pngs, (
                    (out.color, tmp / "images" / name, "colour"),
                    (depth_png(out.depth), tmp / "ground_truth" / "depth" / name, "depth"),
                    (labels_png(out.labels), tmp / "ground_truth" / "labels" / name, "labels"))))
                cam_images.append(_camera_image(name, view, q, T_fk, kin))
                gt_images.append(_truth_image(name, view, T_render, dp, dr, joints_now, sc, data))
                bar.update(1)
            bar.close()
            unreachable = [{"ring": v.ring, "azimuth_deg": float(np.rad2deg(v.azimuth)),
                            "elevation_deg": float(np.rad2deg(v.elevation)), "reason": v.reason}
                           for v in plan.unreachable]
            records = {
                "cameras.json": _cameras_json(sc, config, rig, cam_images, plan),
                "capture.json": _capture_json(sc, config, plan_cfg, plan, len(to_take), free,
                                              unreachable, kin, arm),
                "ground_truth/poses.json": _poses_json(sc, config, joints_config, true_sphere,
                                                       gt_images),
            }
            for w in writes:
                png_cpu += w.result()  # raises the first failed write
            for rel, obj in records.items():
                (tmp / rel).write_text(json.dumps(obj, indent=2) + "\n")
            workers.raise_if_interrupted()
            publish_dir(tmp, out_dir)
        except BaseException:
            bar.close()
            writer.shutdown(wait=True, cancel_futures=True)
            raise
        finally:
            writer.shutdown(wait=True)
    t_end = time.perf_counter()
    cpu = time.process_time() - cpu_start
    n = max(1, len(to_take))
    result = CaptureResult(
        out_dir=out_dir, n_planned=len(plan.views), n_captured=len(to_take),
        unreachable=unreachable, free_camera=free, max_fk_position_error=max_dp,
        max_fk_rotation_error=max_dr, plan_cached=plan_cached,
        timings={"plan_s": t_plan - t_start, "move_s": t_move, "render_s": t_render,
                 "total_s": t_end - t_start,
                 "render_ms_per_image": 1e3 * t_render / n,
                 # CPU seconds (all threads: main, llvmpipe's rasteriser, the PNG writer);
                 # render_cpu_s is the rest: rendering, ground-truth conversion, bookkeeping
                 "cpu_s": cpu, "plan_cpu_s": plan_cpu, "move_cpu_s": move_cpu,
                 "png_cpu_s": png_cpu, "render_cpu_s": cpu - plan_cpu - move_cpu - png_cpu})
    log.info("%s config %s: %d/%d views captured into %s (%.1f s)", sc.name, config,
             result.n_captured, result.n_planned, out_dir, result.timings["total_s"])
    return result


# ------------------------------------------------------------------------------------ the records
def _camera_image(name: str, view: views.View, q, T_fk, kin: robot.ArmKinematics) -> dict:
    """An image's entry in cameras.json: what the robot knows (its joints, their FK)."""
    return {
        "file": name,
        "pose_source": "arm_fk" if view.reachable else "free_camera",
        "q": None if q is None else [float(x) for x in q],
        "T_world_camera": None if T_fk is None else as_list(T_fk),
        "T_world_flange": None if q is None else as_list(kin.frame_pose(q, "flange")),
    }


def _truth_image(name: str, view: views.View, T_render, dp, dr, joints_now: dict, sc: Scene,
                 data: mujoco.MjData) -> dict:
    """An image's entry in ground_truth/poses.json: the true camera and object poses."""
    return {
        "file": name,
        "view": {"ring": view.ring, "azimuth_deg": float(np.rad2deg(view.azimuth)),
                 "elevation_deg": float(np.rad2deg(view.elevation)),
                 "distance_m": view.distance, "roll_deg": view.roll_deg},
        "T_world_camera": as_list(T_render),
        "fk_position_error_m": dp,
        "fk_rotation_error_rad": dr,
        "object_joints": joints_now,
        "link_poses": {li.name: as_list(np.r_[np.c_[
            data.xmat[li.body_id].reshape(3, 3), data.xpos[li.body_id]], [[0, 0, 0, 1]]])
            for li in sc.links},
    }


def object_region(plan: views.ViewPlan) -> dict:
    """cameras.json's ``region`` (see :mod:`artrecon.io`): where the robot found the object, as
    points whose convex hull holds it. The survey's hull (the convex hull of the visual hull it
    carved from its own photographs, which holds the object); a plan without one gives the
    corners of the cube around the survey's sphere."""
    hull = (plan.survey or {}).get("hull_vertices")
    if hull is not None and len(hull) >= 4:
        return {"points": [[float(x) for x in p] for p in hull],
                "source": "the survey's visual hull (convex hull of its voxels)"}
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
    points = np.asarray(plan.centre, float) + plan.radius * corners
    return {"points": points.tolist(), "source": "the cube around the survey's sphere"}


def _cameras_json(sc: Scene, config: str, rig: Rig, images: list[dict],
                  plan: views.ViewPlan) -> dict:
    """cameras.json: the intrinsics, each image's FK poses and where the object is (what
    artrecon reads)."""
    return {
        "format": "artrecon-capture/1",
        "scene": sc.name,
        "config": config,
        "convention": "OpenCV camera (x right, y down, z forward); T_world_camera maps camera "
                      "coordinates to world coordinates; metres, radians",
        "width": rig.width, "height": rig.height, "K": as_list(rig.K),
        "joint_names": list(rig.kin.joint_names),
        "images": images,
        "region": object_region(plan),
    }


def _capture_json(sc: Scene, config: str, cfg: views.ViewPlanConfig, plan: views.ViewPlan,
                  n_captured: int, free: list[int], unreachable: list[dict],
                  kin: robot.ArmKinematics, arm: Arm) -> dict:
    """capture.json: the ring layout asked for, the rings chosen, what was captured and not."""
    return {
        "scene": sc.name, "config": config, "seed": cfg.seed, "views_per_ring": cfg.views_per_ring,
        # where the rings look: the object's sphere as the survey found it (what the robot knows)
        "object_sphere": {"centre": [float(x) for x in plan.centre], "radius": float(plan.radius),
                          "survey": plan.survey},
        "elevations_deg": list(cfg.elevations_deg),
        "top_elevations_deg": list(cfg.top_elevations_deg),
        "fill": cfg.fill, "fill_range": list(cfg.fill_range),
        "max_elevation_shift_deg": cfg.max_elevation_shift_deg,
        "rings": [{"ring": r.index, "n_views": r.n_views,
                   "desired_elevation_deg": float(np.rad2deg(r.desired_elevation)),
                   "elevation_deg": float(np.rad2deg(r.elevation)),
                   "distance_m": r.distance, "fill": r.fill,
                   "candidates_tried": r.candidates_tried} for r in plan.rings],
        "planned": len(plan.views), "captured": n_captured,
        "free_camera_images": free, "unreachable": unreachable,
        "max_path_deviation": dict(zip(kin.joint_names,
                                       arm.max_path_deviation.tolist(), strict=True)),
    }


def _poses_json(sc: Scene, config: str, joints_config: dict, true_sphere: tuple,
                images: list[dict]) -> dict:
    """ground_truth/poses.json: the object's configuration, links, label legend, true poses."""
    link_names = [li.name for li in sc.links]
    return {
        "scene": sc.name, "config": config,
        "object_joints": joints_config,
        "object_links": link_names,
        "object_bounding_sphere": {"centre": [float(x) for x in true_sphere[0]],
                                   "radius": float(true_sphere[1])},
        "label_legend": {**{str(i): n for i, n in enumerate(link_names)},
                         str(LABEL_PNG_ARM): "arm", str(LABEL_PNG_STAGE): "stage",
                         str(LABEL_PNG_BACKGROUND): "background"},
        "depth_png_scale_m": DEPTH_PNG_SCALE,
        "images": images,
    }
