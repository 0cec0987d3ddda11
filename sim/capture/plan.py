"""The view plan of a capture (rings and IK, :func:`sim.views.plan_capture`), cached on disk:
it depends on the compiled scene, the start state, the camera, the ring layout, the seed, the
survey's settings and the planning code (the survey's renderer among it: the survey photographs
the table to find the object), and on nothing of the capture's motion or files."""

from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path

import mujoco
import numpy as np
import pinocchio

import artrecon.geometry
from sim import cache, robot, views

#: File of a cached view plan (:func:`plan_views`), in its stage folder of the plan cache.
PLAN_FILE = "plan.json"


@functools.cache
def plan_sources() -> str:
    """Hash of the code a view plan runs (:mod:`sim.views` and what it imports of ``sim``,
    :mod:`artrecon.geometry` that the kinematics use), once per process: the code this
    process loaded (see :func:`sim.evaluate.stages.freeze_code_keys`)."""
    return cache.hash_bytes(cache.closure_hash(views).encode(),
                            cache.closure_hash(artrecon.geometry, "artrecon").encode())


def plan_inputs(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                K: np.ndarray, width: int, height: int, config: views.ViewPlanConfig) -> dict:
    """Everything :func:`sim.views.plan_capture` reads, as a dict for the plan cache's key.

    The compiled model itself (MuJoCo's binary model file, hashed: the scene file and every
    file it includes or references, the arm, the joint holds' targets), the state the plan
    starts from (joint positions, mocap poses), the arm's URDF when its kinematics come from
    one, the camera, the ring layout and seed, the planning code and the numerical packages.
    A scene file edited so that its compiled model changes gives another key; an edit that
    compiles to the same model (a comment) keeps the plan, which is the same plan.
    """
    buf = np.empty(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    state = cache.hash_bytes(*(np.ascontiguousarray(a, dtype=np.float64).tobytes()
                               for a in (data.qpos, data.mocap_pos, data.mocap_quat)))
    urdf = None
    if kin.spec.urdf is not None:
        urdf = cache.hash_files([robot.ROOT / kin.spec.urdf], root=robot.ROOT)
    return {"model": cache.hash_bytes(buf.tobytes()), "state": state, "arm": kin.spec.name,
            "urdf": urdf, "K": np.asarray(K, dtype=float).tolist(), "size": [width, height],
            "plan": dataclasses.asdict(config), "survey": dataclasses.asdict(views.SurveyConfig()),
            "code": plan_sources(),
            "versions": {"numpy": np.__version__, "mujoco": mujoco.__version__,
                         "pinocchio": pinocchio.__version__}}


def plan_views(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
               K: np.ndarray, width: int, height: int, config: views.ViewPlanConfig, *,
               cell: views.KnownCell, cache_dir=None, stage: str = "plan",
               progress=None) -> tuple[views.ViewPlan, bool]:
    """:func:`sim.views.plan_capture`, or the same plan read from ``cache_dir``.

    With ``cache_dir``, the plan is a stage of :func:`sim.cache.cached_stage` keyed by
    :func:`plan_inputs`: ``cache_dir/<stage>-<hash>/plan.json``, solved and stored when absent.
    The file holds every number of the plan exactly (:func:`sim.views.plan_to_json`), so a
    capture from a cached plan writes the same files as one that solved it. A large object's
    plan is most of its capture's CPU (drawer: 15 of 29 s), and it depends on none of what
    later code changes of the capture (rendering, the arm's motion, the files) touch.

    Returns
    -------
    plan : sim.views.ViewPlan
    cached : bool
        The plan came from the cache.
    """
    if cache_dir is None:
        return views.plan_capture(model, data, kin, K, width, height, config,
                                  progress=progress, cell=cell), False
    solved = []

    def build(folder: Path) -> dict:
        plan = views.plan_capture(model, data, kin, K, width, height, config, progress=progress,
                                  cell=cell)
        (folder / PLAN_FILE).write_text(json.dumps(views.plan_to_json(plan)) + "\n")
        solved.append(plan)
        return {"views": len(plan.views), "reachable": len(plan.reachable)}

    folder, _, hit = cache.cached_stage(cache_dir, stage,
                                        plan_inputs(model, data, kin, K, width, height, config),
                                        build)
    if not hit:
        return solved[0], False
    plan = views.plan_from_json(json.loads((folder / PLAN_FILE).read_text()))
    if progress is not None:
        progress.update(len(plan.views))
    return plan, True
