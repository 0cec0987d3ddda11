"""Pieces of the plan that each cost a bundled scene its manipulation (issue 19): a motion that
holds an arm joint at its limit, grasp candidates on the rim of a face or beside a fixed part,
tries spent on one edge, and the feed-forward pushing into what the fingertips touch."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from synthetic import box_faces

import sim  # noqa: F401
from artrecon.model import ArticulatedModel, Link
from sim.manipulate import GraspCandidate, JointEstimate, PlanningConfig, build_world, fresh_data
from sim.manipulate import candidates as C
from sim.manipulate import planning as P
from sim.manipulate.execute import GripConfig, _Run
from sim.scene import load_scene


def _path(n=40):
    s = np.linspace(0.0, 1.0, n + 1)[:, None]
    return np.hstack([0.3 * s, -0.2 * s + 0.05 * s ** 2, 0.1 * np.sin(s)])


def test_a_smooth_joint_path_has_no_kink():
    share, _ = P._kink(_path())
    assert share < 0.05


def test_a_joint_stopped_at_its_limit_is_a_kink():
    """The third joint stops at 60% of the path (its limit) and the first takes over its part:
    the kind of path that jolted cabinet's door (21.9 N) and drawer (9.7 N)."""
    q = _path()
    q[:, 2] = np.linspace(0.0, 0.25, len(q))
    stop = 24
    q[stop:, 2] = q[stop, 2]
    q[stop:, 0] += np.linspace(0.0, 0.1, len(q) - stop)
    share, at = P._kink(q)
    assert share > PlanningConfig().max_path_kink
    assert abs(at - stop) <= 2


def test_the_plans_ik_stays_inside_the_limits():
    kin = P.PlanningWorld.from_scene(build_world(load_scene("pliers"))).kin
    lower, upper = kin.lower.copy(), kin.upper.copy()
    margin = PlanningConfig().joint_limit_margin
    with P._limits_narrowed(kin, margin):
        q = kin.clip(upper + 1.0)
        assert np.all(q <= upper - margin + 1e-12)
    assert np.array_equal(kin.lower, lower) and np.array_equal(kin.upper, upper)


def _face(step=0.002, half=0.02):
    """A flat square face (z = 0, normal +z) sampled every ``step``."""
    g = np.arange(-half, half + 1e-9, step)
    x, y = np.meshgrid(g, g)
    pts = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    return pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1))


def test_a_point_on_the_rim_of_its_face_is_no_candidate():
    pts, nrm = _face()
    tree, cfg, n = cKDTree(pts), PlanningConfig(), np.array([0.0, 0.0, 1.0])
    assert C._surrounded(np.zeros(3), n, pts, nrm, tree, cfg)
    assert not C._surrounded(np.array([0.02, 0.0, 0.0]), n, pts, nrm, tree, cfg)
    assert not C._surrounded(np.array([0.019, 0.019, 0.0]), n, pts, nrm, tree, cfg)


def test_a_candidates_normal_is_its_surfaces_not_its_points():
    """Point normals tilted at random by up to ~20 deg on a flat face (the dense stage's noise on
    scissors' rings): the candidate's normal is the face's within a degree, and a fitted normal
    keeps the side the points face."""
    rng = np.random.default_rng(0)
    pts, _ = _face()
    tilt = rng.normal(0.0, 0.2, (len(pts), 2))
    nrm = np.c_[tilt, np.ones(len(pts))]
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    tree, cfg = cKDTree(pts), PlanningConfig()
    mean = nrm[np.linalg.norm(pts, axis=1) < 0.003].mean(axis=0)
    n = C._plane_normal(np.zeros(3), mean / np.linalg.norm(mean), pts, nrm, tree, cfg)
    assert np.degrees(np.arccos(n[2])) < 1.0
    down = C._plane_normal(np.zeros(3), -mean / np.linalg.norm(mean), pts, -nrm, tree, cfg)
    assert down[2] < -0.9998


def test_candidates_clear_of_the_fixed_parts_come_first():
    est = JointEstimate("revolute", [0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    up = np.array([1.0, 0.0, 0.0])
    near = GraspCandidate(np.array([0.20, 0.0, 0.0]), up, clearance=0.01)  # longest lever
    clear = GraspCandidate(np.array([0.12, 0.0, 0.0]), up, clearance=0.05)
    touching = GraspCandidate(np.array([0.25, 0.0, 0.0]), up, clearance=0.002)
    ranked = P.rank([touching, near, clear], est, prefer_hidden=True)
    assert [c.point[0] for c in ranked] == [0.12, 0.20, 0.25]


def test_a_hidden_candidate_at_a_seam_comes_after_the_clear_ones():
    """Hidden candidates come first, but not one a few millimetres from a fixed part: there the
    segmentation is least sure (the imported chest's lid was grasped on its front edge, 4.9 mm
    above the carcass's points, and the gripper closed on the carcass)."""
    est = JointEstimate("revolute", [0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    up = np.array([1.0, 0.0, 0.0])
    seam = GraspCandidate(np.array([0.25, 0.0, 0.0]), up, hidden=True, clearance=0.005)
    hidden = GraspCandidate(np.array([0.10, 0.0, 0.0]), up, hidden=True, clearance=0.01)
    seen = GraspCandidate(np.array([0.20, 0.0, 0.0]), up, clearance=0.05)
    ranked = P.rank([seam, seen, hidden], est, prefer_hidden=True)
    assert [c.point[0] for c in ranked] == [0.10, 0.20, 0.25]
    assert [c.point[0] for c in P.rank([seam, seen], est, prefer_hidden=True)] == [0.20, 0.25]


def test_tries_after_a_failure_are_spread_along_the_link():
    n = np.array([0.0, 0.0, 1.0])
    edge = [GraspCandidate(np.array([0.006 * k, 0.0, 0.0]), n) for k in range(20)]
    order = [c.point[0] for c in P._spread(edge, 0.015, 40)]
    assert sorted(order) == sorted(c.point[0] for c in edge)  # nothing lost
    first = order[:len([x for x in order if x in (0.0, 0.018, 0.036, 0.054, 0.072, 0.09,
                                                   0.108)])]
    assert np.all(np.diff(first) >= 0.015 - 1e-12)
    assert len(list(P._spread(edge, 0.015, 5))) == 5


def test_the_feed_forward_ignores_contacts():
    """The arm's feed-forward is its own inverse dynamics: with the fingertips 1 cm into the
    table it is what it is with the table gone (with contacts, MuJoCo's inverse dynamics turns
    the contact into torque pushing into it: a fingertip grazing the object spiked the grip)."""
    import mujoco

    world = build_world(load_scene("pliers"))
    data = fresh_data(world)
    m = world.model
    table = [g for g in range(m.ngeom) if (m.geom(g).name or "") == "table_top"]
    assert table
    top = data.geom_xpos[table[0]][2] + m.geom_size[table[0]][2]
    T = np.diag([1.0, -1.0, -1.0, 1.0])  # grasp frame's z (the approach) pointing down
    T[:3, 3] = [0.25, 0.0, top + 0.005]  # the fingertips reach 15 mm beyond it
    ik = world.kin.solve_ik(T, "grasp", data.qpos[world.qidx], seed=0)
    assert ik.success
    q = ik.q

    def inverse(model):
        inv = mujoco.MjData(model)
        inv.qpos[:] = data.qpos
        inv.qpos[world.qidx] = q
        mujoco.mj_inverse(model, inv)
        return inv.qfrc_inverse[world.vidx].copy(), inv.ncon

    run = _Run(world, data, GripConfig(), None)
    with_contacts, ncon = inverse(m)
    assert ncon > 0 and not np.allclose(with_contacts, inverse(run._inv_model)[0])
    u = run.command(q)
    run._inv_model.geom_contype[table] = 0
    run._inv_model.geom_conaffinity[table] = 0
    run._inv_model.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    np.testing.assert_allclose(u, run.command(q), atol=1e-9)


@pytest.mark.parametrize("flag", ["mjDSBL_CONTACT", "mjDSBL_EQUALITY"])
def test_the_feed_forward_model_has_no_contacts_nor_welds(flag):
    import mujoco

    world = build_world(load_scene("pliers"))
    run = _Run(world, fresh_data(world), GripConfig(), None)
    bit = int(getattr(mujoco.mjtDisableBit, flag))
    assert run._inv_model.opt.disableflags & bit
    assert not world.model.opt.disableflags & bit  # the physics keeps its contacts


def test_the_fingers_straddle_a_handle_rather_than_rest_on_it():
    """A handle (a bar 16 mm high and 10 cm long, across cabinet_door_only's door) grasped on
    its front face: with the gripper rolled by 135 deg the finger pads rest on the bar's edges,
    3 mm above the model's surface (where the true surface lies further out, as at a handle's
    edges the reconstruction rounds, they press into it: the grasp cabinet_door_only lost at
    1% of its turn, fingers along its handle); rolled by 90 deg the fingers are either side of
    the bar and touch nothing. The plan takes the roll whose gripper touches nothing, though
    the other's travel is shorter."""
    from artrecon.model import ArticulatedModel, Joint, Link

    world = build_world(load_scene("cabinet_door_only"))
    handle, hn = box_faces(np.array([0.142, 0.06, 0.555]), np.array([0.006, 0.05, 0.008]))
    door, dn = box_faces(np.array([0.114, 0.0, 0.556]), np.array([0.006, 0.137, 0.0925]),
                            step=0.004)
    top, tn = box_faces(np.array([0.0, 0.0, 0.764]), np.array([0.12, 0.15, 0.006]),
                           step=0.004)
    links = [Link(points=p, match_indices=np.full(len(p), -1), normals=n, name=name)
             for p, n, name in ((top, tn, "carcass"),
                                (np.vstack([door, handle]), np.vstack([dn, hn]), "door"))]
    hinge = Joint("revolute", np.array([0.0, 0.0, -1.0]), np.array([0.12, -0.138, 0.55]),
                  parent=0, child=1, state_b=np.deg2rad(30.0), name="hinge")
    pw = P.PlanningWorld.from_model(world, ArticulatedModel(links=links, joints=[hinge],
                                                            scale_known=True))
    est = JointEstimate("revolute", hinge.axis_direction, hinge.axis_point)
    cand = GraspCandidate(np.array([0.148, 0.06, 0.555]), np.array([1.0, 0.0, 0.0]))
    q0 = fresh_data(world).qpos[world.qidx]

    def plan(rolls):
        p, why = P.plan_candidate(pw, cand, est, np.deg2rad(30.0), q0, 0, {1}, rolls)
        assert p is not None, why
        return p

    across, diagonal = plan((90.0,)), plan((135.0,))
    assert across.gripper_contacts == 0 and diagonal.gripper_contacts > 0
    travel = [float(np.sum(np.abs(p.q_pre - q0))) for p in (across, diagonal)]
    assert travel[1] < travel[0]
    assert plan((135.0, 90.0)).roll_deg == 90.0


def test_the_plan_starts_its_ik_again_from_home_when_the_arms_pose_gives_none(monkeypatch):
    """The plan's IK starts from where the arm is; when no roll passes from there (an IK branch
    whose arm meets the model at the grasp: cabinet's door from the fresh view's pose, 40
    candidates refused), it starts again from the arm's home keyframe, and the travel still
    starts where the arm is. From home itself it does not try twice."""
    world = build_world(load_scene("pliers"))
    pw = P.PlanningWorld.from_model(world, ArticulatedModel(
        links=[Link(points=np.zeros((0, 3)), match_indices=np.zeros(0, int), name="x")],
        joints=[], scale_known=True))
    calls = []

    def fake(pw_, cand, est, amount, q_start, q_seed, seed, moving, rolls):
        calls.append((np.array(q_start), np.array(q_seed)))
        return (None, "refused") if len(calls) == 1 else ("a plan", "")

    monkeypatch.setattr(P, "_plan_candidate", fake)
    cand = GraspCandidate(np.array([0.0, 0.0, 0.5]), np.array([0.0, 0.0, 1.0]))
    est = JointEstimate("revolute", np.array([0.0, 0.0, 1.0]), np.zeros(3))
    q_arm = pw.q_home + 0.3
    assert P.plan_candidate(pw, cand, est, 0.5, q_arm, 0) == ("a plan", "")
    assert len(calls) == 2
    assert np.allclose(calls[0][1], q_arm) and np.allclose(calls[1][1], pw.q_home)
    assert all(np.allclose(q, q_arm) for q, _ in calls)  # the travel starts where the arm is
    calls.clear()
    assert P.plan_candidate(pw, cand, est, 0.5, pw.q_home, 0) == (None, "refused")
    assert len(calls) == 1


def test_tangents_are_an_orthonormal_frame_and_the_cross_products_of_numpy():
    """The grasp planner's tangent frame: u, v unit, orthogonal to each other and to the
    normal, (u, v, n) right-handed, and bit for bit the frame np.cross gave (the planner's
    choices must not move with a faster cross product), near the pole too."""
    rng = np.random.default_rng(3)
    normals = rng.normal(size=(2000, 3))
    normals[:200] = [0.01, -0.02, 1.0]  # |n_z| >= 0.9: the other reference axis
    normals[200:400, 2] = -np.abs(normals[200:400, 2]) * 50
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    for n in normals:
        u, v = C.tangents(n)
        ref = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        u0 = np.cross(n, ref)
        u0 /= np.linalg.norm(u0)
        assert np.array_equal(u, u0) and np.array_equal(v, np.cross(n, u0))
        assert abs(u @ n) < 1e-12 and abs(v @ n) < 1e-12 and abs(u @ v) < 1e-12
        assert np.linalg.norm(u) == pytest.approx(1.0) and np.linalg.norm(v) == pytest.approx(1.0)
        assert np.cross(u, v) @ n == pytest.approx(1.0)
