"""Viewpoint planning for eye-in-hand capture: rings of views around the object, reached by the arm.

The object's bounding sphere, as the robot's survey finds it from its own photographs
(:func:`sim.views.survey.survey_object`: the visual hull of the object's silhouettes against the
empty cell, never the model's geometry), fixes the ring centre and, with the wrist camera's field
of view, the band of camera distances at which the object fills a good share of the image
(:attr:`ViewPlanConfig.fill_range`). Every view looks at the sphere's
centre; each is solved with the arm's inverse kinematics (rail and arm together, joint limits
respected, :func:`sim.robot.solve_view_ik`: in closed form for the PUMA) and checked for
collisions of the arm links in MuJoCo, in the cell as the robot knows it
(:class:`sim.views.known.KnownCell`: the table, the floor, the arm itself and, for the object,
the convex hull of the survey's visual hull; never the object's own geoms).

:func:`plan_capture` chooses each ring before committing to it: the distance in the band nearest
the preferred fill and, only if no distance gives a ring the arm reaches everywhere without a
collision, the elevation nearest the desired one (within
:attr:`ViewPlanConfig.max_elevation_shift_deg`). A candidate ring is first probed at a few
azimuths, then solved in full. Views that the arm cannot reach on the best ring found are reported
with the reason, never silently dropped.
"""


from __future__ import annotations

import logging
from dataclasses import replace

import mujoco
import numpy as np

from sim import robot
from sim.views.known import KnownCell
from sim.views.records import ELEVATION_LIMITS_DEG, Ring, View, ViewPlan, ViewPlanConfig
from sim.views.rings import (
    fill_at_distance,
    order_for_rail,
    ring_distance,
    ring_phases,
    ring_size,
    ring_views,
)
from sim.views.solve import check_paths, solve_views
from sim.views.survey import SurveyConfig, survey_object

log = logging.getLogger(__name__)


def candidates(config: ViewPlanConfig, desired_deg: float, radius: float, K, width: int,
                height: int, lowest_deg: float, highest_deg: float):
    """(elevation in degrees, distance, fill) of the candidate rings for one desired elevation:
    the desired elevation first with every distance in the fill band (nearest the preferred fill
    first, the closer of two equally near), then elevations further and further off (towards
    45 degrees first), each with every distance."""
    lo, hi = config.fill_range
    fills = np.round(np.arange(lo, hi + 1e-9, config.fill_step), 6).tolist() + [config.fill]
    fills = sorted(set(fills), key=lambda f: (abs(f - config.fill), -f))
    distances = []
    for f in fills:
        d = ring_distance(radius, K, width, height, f, config.min_ring_distance)
        if all(abs(d - e) > 1e-3 for e in distances):  # the minimum distance clamps small objects
            distances.append(d)
    shifts = [0.0]
    k = 1
    while k * config.elevation_step_deg <= config.max_elevation_shift_deg + 1e-9:
        step = k * config.elevation_step_deg
        shifts += [-step, step] if desired_deg > 45.0 else [step, -step]
        k += 1
    for shift in shifts:
        el = desired_deg + shift
        if not lowest_deg <= el <= highest_deg:
            continue
        for d in distances:
            yield el, d, fill_at_distance(radius, K, width, height, d)


def plan_capture(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                 K: np.ndarray, width: int, height: int, config: ViewPlanConfig, *,
                 progress=None, survey_config: SurveyConfig = SurveyConfig(),
                 cell: KnownCell) -> ViewPlan:
    """Choose every ring so that the arm reaches all its views without a collision, and solve them.

    For each ring (full rings, then top rings) the candidates of :func:`candidates` are tried in
    order: a candidate is probed at ``config.probe_views`` evenly spread views (few IK restarts,
    stopping at the first failure), then solved view by view up to its first unreachable view
    (:func:`solve_views`) and the moves into its views checked (:func:`check_paths`); the first
    whose views are all reachable, and whose moves touch nothing, is taken. If none is, the
    candidates that passed their probe are solved in full (second chances included) and the
    ring with the most reachable views is taken; its other views are reported unreachable.

    Parameters
    ----------
    model, data
        The scene in the configuration to photograph (``data`` after ``mj_forward``).
    kin : robot.ArmKinematics
    K : (3, 3) float
        Wrist camera intrinsics; ``width``, ``height`` its image size (px).
    config : ViewPlanConfig
    progress : tqdm-like, optional
        ``update(n)`` with the views of each ring once it is chosen.
    survey_config : sim.views.survey.SurveyConfig
        How the survey looks for the object before the rings are planned.
    cell : sim.views.known.KnownCell
        The scene file compiled for planning (without the object): the survey's and the rings'
        IK and clearance are checked there, the rings' with the survey's hull added.
        ``model`` and ``data`` only take the survey's photographs.

    Returns
    -------
    ViewPlan
        Rings and views in capture order (ring by ring, each swept in one rail direction).
    """
    survey = survey_object(model, data, kin, K, width, height, config, survey_config,
                           cell=cell)
    centre, radius = survey.centre, survey.radius
    # the object as the robot knows it: the hull the survey carved, not the object's geoms
    known = cell.with_hull(survey.hull).at(data.qpos)
    model, data = known.model, known.data
    lowest = min((*config.elevations_deg, *config.top_elevations_deg))
    highest = max((*config.elevations_deg, *config.top_elevations_deg))
    lowest = max(ELEVATION_LIMITS_DEG[0], lowest - config.max_elevation_shift_deg)
    highest = min(ELEVATION_LIMITS_DEG[1], highest + config.max_elevation_shift_deg)
    n_full = len(config.elevations_deg)
    plan = ViewPlan(centre=centre, radius=radius, survey=survey.to_json())
    q_last = None
    for i, (desired, az0) in enumerate(zip((*config.elevations_deg, *config.top_elevations_deg),
                                           ring_phases(config), strict=True)):
        top = i >= n_full
        best: tuple[int, Ring, list[View]] | None = None
        screened: list[tuple[Ring, list[View]]] = []  # passed the probe, not whole
        tried = 0
        for el_deg, d, fill in candidates(config, desired, radius, K, width, height, lowest,
                                           highest):
            tried += 1
            el = float(np.deg2rad(el_deg))
            ring = Ring(index=i, desired_elevation=float(np.deg2rad(desired)), elevation=el,
                        distance=float(d), fill=float(fill),
                        n_views=ring_size(el, config.views_per_ring, top), azimuth0=az0,
                        top=top, candidates_tried=tried)
            members = order_for_rail(ring_views(centre, ring), kin)
            first = len(plan.views)
            for k, v in enumerate(members):
                v.index = first + k
            step = max(1, len(members) // config.probe_views)
            probe = members[::step]
            solve_views(model, data, kin, probe, seed=config.seed, q_start=q_last,
                        restarts=config.probe_ik_restarts, stop_at_first_failure=True,
                        config=config)
            if not all(v.reachable for v in probe):
                log.debug("ring %d at %.1f deg, %.3f m: probe failed (%s)", i, el_deg, d,
                          next(v.reason for v in probe if not v.reachable))
                if best is None:
                    best = (-1, ring, members)
                continue
            # screened in full, stopping at its first unreachable view: a ring is taken only
            # whole, and a failing view costs every IK restart, so solving the rest of a ring
            # that already failed (as this did until 2026-11) spent most of a large object's
            # plan (drawer: 42 candidates for its lowest ring)
            solve_views(model, data, kin, members, seed=config.seed, q_start=q_last,
                        stop_at_first_failure=True, config=config)
            if all(v.reachable for v in members):
                check_paths(model, data, kin, members, q_last, config)
                if all(v.reachable for v in members):
                    best = (len(members), ring, members)
                    break
            log.debug("ring %d at %.1f deg, %.3f m: not every view reachable", i, el_deg, d)
            screened.append((ring, members))
        else:
            # no candidate is whole: the one with the most reachable views, each solved in full
            # (with its second chances from the other side)
            for ring_c, members_c in screened:
                solve_views(model, data, kin, members_c, seed=config.seed, q_start=q_last,
                            config=config)
                check_paths(model, data, kin, members_c, q_last, config)
                n_ok = sum(v.reachable for v in members_c)
                if best is None or n_ok > best[0]:
                    best = (n_ok, ring_c, members_c)
                if n_ok == len(members_c):
                    break
        n_ok, ring, members = best
        if n_ok < 0:
            # no candidate passed its probe: solve the preferred one in full, to report why
            solve_views(model, data, kin, members, seed=config.seed, q_start=q_last,
                        config=config)
            check_paths(model, data, kin, members, q_last, config)
        if any(not v.reachable for v in members):
            log.warning("ring %d (desired %.0f deg): no ring within %.0f deg and fills %s is "
                        "reachable everywhere; %d of %d views unreachable at %.1f deg, %.3f m",
                        i, desired, config.max_elevation_shift_deg, config.fill_range,
                        sum(not v.reachable for v in members), len(members),
                        np.rad2deg(ring.elevation), ring.distance)
        ring = replace(ring, candidates_tried=tried)
        log.info("ring %d: %d views at %.1f deg (desired %.0f), %.3f m (fill %.2f), %d "
                 "candidates tried", i, ring.n_views, np.rad2deg(ring.elevation), desired,
                 ring.distance, ring.fill, tried)
        plan.rings.append(ring)
        plan.views.extend(members)
        reached = [v for v in members if v.reachable]
        if reached:
            q_last = reached[-1].q
        if progress is not None:
            progress.update(len(members))
    return plan
