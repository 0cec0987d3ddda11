"""The fresh view: one more image after a capture, from an arm pose that neither image set holds,
for registration by PnP and hand-eye (:mod:`artrecon.register`)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from artrecon.files import work_dir
from sim import render, robot, views
from sim.capture.arm import Arm
from sim.capture.files import as_list, check_out_dir, png_bytes
from sim.capture.rig import CaptureError, make_rig, true_camera_pose
from sim.capture_config import CaptureConfig


@dataclass
class FreshView:
    """What :func:`capture_fresh_view` wrote."""

    image: Path
    """the image file"""
    pose_file: Path
    """``{"q", "T_world_flange", "T_world_camera"}``: what the robot knows (FK of its joints)"""
    q: np.ndarray
    """the arm's joint angles at the view (rail first)"""
    T_world_flange: np.ndarray
    """flange pose from FK (m)"""
    T_world_camera_true: np.ndarray
    """the camera's true pose (scoring only; ``ground_truth.json`` beside the image)"""


def capture_fresh_view(scene, config: str, q_start, out_dir, *, fill: float = 0.6,
                       seed: int = 0, capture_config: CaptureConfig = CaptureConfig(),
                       plan_config: views.ViewPlanConfig = views.ViewPlanConfig(),
                       target: tuple | None = None) -> FreshView:
    """One more image after the capture, from an arm pose that neither image set holds.

    The arm starts at ``q_start`` (where the capture left it), plans a view of ``target``
    (``(centre, radius)`` of the object's sphere as the robot knows it, optionally with the
    vertices of the survey's hull as a third item: the capture's survey, capture.json's
    ``object_sphere``; None: the arm surveys the table again, :func:`sim.views.survey_object`)
    at
    ``capture_config.fresh_elevation_deg`` half a capture step off its current azimuth (the
    other ``fresh_azimuth_offsets_deg`` when that one is out of reach), at the distance where the
    object fills ``fill`` of the image, moves there in physics along a checked line and
    photographs the object. The view is reached and checked with the tunables of
    ``plan_config`` (IK restarts, rolls, clearance, path step, smallest distance; its ring
    layout is not read), IK restarts seeded with ``seed``. Writes ``out_dir/fresh.png``,
    ``out_dir/pose.json`` (joint angles, flange and camera pose from forward kinematics: what
    the robot knows) and ``out_dir/ground_truth.json`` (the true camera pose, scoring only),
    whole or not at all. The view and its path are checked in the cell as the robot knows it
    (:class:`sim.views.KnownCell`): the survey's hull, or without one the target's sphere,
    stands for the object.

    Raises
    ------
    CaptureError
        No offset gives a reachable, collision-free view with a clear path.
    """
    out_dir = check_out_dir(Path(out_dir), overwrite=False)
    rig = make_rig(scene, config)
    sc, model, data, kin = rig.scene, rig.model, rig.data, rig.kin
    K, width, height = rig.K, rig.width, rig.height
    q_start = np.asarray(q_start, dtype=float)
    data.qpos[robot.qpos_indices(model, kin)] = q_start
    mujoco.mj_forward(model, data)
    cell = views.KnownCell(sc.path)
    if target is None:
        survey = views.survey_object(model, data, kin, K, width, height, plan_config,
                                     cell=cell)
        target = survey.centre, survey.radius, survey.hull
    centre, radius = np.asarray(target[0], dtype=float), float(target[1])
    hull = target[2] if len(target) > 2 and target[2] is not None else _sphere_hull(centre,
                                                                                     radius)
    known = cell.with_hull(np.asarray(hull, dtype=float)).at(data.qpos)
    distance = views.ring_distance(radius, K, width, height, fill,
                                   plan_config.min_ring_distance)
    eye = kin.camera_pose(q_start)[:3, 3] - centre
    az0 = float(np.arctan2(eye[1], eye[0]))
    el = np.deg2rad(capture_config.fresh_elevation_deg)
    reasons = []
    chosen = None
    for k, off in enumerate(capture_config.fresh_azimuth_offsets_deg):
        az = az0 + np.deg2rad(off)
        pos = centre + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                            np.sin(el)])
        view = views.View(k, 0, az, el, distance, robot.look_at_pose(pos, centre))
        views.solve_views(known.model, known.data, kin, [view], seed=seed, q_start=q_start,
                          config=plan_config)
        if view.reachable:
            views.check_paths(known.model, known.data, kin, [view], q_start=q_start,
                              config=plan_config)
        if view.reachable:
            chosen = view
            break
        reasons.append(f"{off:+.0f} deg: {view.reason}")
    if chosen is None:
        raise CaptureError(f"no fresh view of {sc.name!r} is reachable near the arm's pose: "
                           + "; ".join(reasons[:3]))
    arm = Arm(model, data, kin, capture_config)
    arm.place(q_start)
    hits = arm.move(chosen.q)
    if hits:
        raise CaptureError(f"the arm touched {', '.join(hits)} on its way to the fresh view of "
                           f"{sc.name!r}")
    q = arm.measured_q()
    T_true = true_camera_pose(data, rig.cam_id)
    renderer = render.MjRenderer(model)
    color = renderer.render(data, K, T_true, width, height).color
    T_flange = kin.frame_pose(q, "flange")
    with work_dir(out_dir) as tmp:
        (tmp / "fresh.png").write_bytes(png_bytes(color, "colour"))
        pose = {"scene": sc.name, "config": config, "q": [float(x) for x in q],
                "joint_names": list(kin.joint_names), "K": as_list(K),
                "T_world_flange": as_list(T_flange),
                "T_world_camera": as_list(kin.camera_pose(q)),
                "view": {"azimuth_deg": float(np.rad2deg(chosen.azimuth)),
                         "elevation_deg": capture_config.fresh_elevation_deg,
                         "distance_m": distance,
                         "roll_deg": chosen.roll_deg}}
        (tmp / "pose.json").write_text(json.dumps(pose, indent=2) + "\n")
        (tmp / "ground_truth.json").write_text(json.dumps(
            {"T_world_camera": as_list(T_true)}, indent=2) + "\n")
        os.replace(tmp, out_dir)  # never over a folder made since the check: not publish_dir()
    return FreshView(out_dir / "fresh.png", out_dir / "pose.json", q, T_flange, T_true)


def _sphere_hull(centre: np.ndarray, radius: float, n: int = 200) -> np.ndarray:
    """Vertices of a polyhedron holding the sphere (``n`` points on a Fibonacci sphere, pushed
    out so that the polyhedron's faces clear the sphere): the object when only its sphere is
    known."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * k
    r = np.sqrt(1.0 - z * z)
    unit = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    # neighbouring points are ~sqrt(4 pi / n) rad apart: a face's centre lies within that angle
    # of its corners, so corners at radius / cos(that angle) keep every face outside the sphere
    return centre + unit * radius / np.cos(np.sqrt(4.0 * np.pi / n))
