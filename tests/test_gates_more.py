"""Issue 10: scoring of multi-joint objects (fast, no capture).

Models built from the ground truth of scraper_truck (a chain of two hinges), cabinet (hinge +
slide) and cabinet_door_only (the drawer left still), with known errors: the joints must be
paired by the links they join, the kinematic tree judged, a static joint reported and never
counted as found or invented, and the link behind a static joint scored as part of its parent.
The accuracy gates of every bundled scene are in tests/test_gates.py.
"""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np
import pytest

import sim  # noqa: F401
from artrecon.model import ArticulatedModel, Joint, Link
from sim import evaluate, metrics
from sim.evaluate import gates
from sim.scene import load_scene

# ------------------------------------------------------------------------------ fast: scoring


def _samples(scene):
    pts, links = evaluate.sample_surface(scene, "a", spacing=0.006, seed=1)
    return pts, links


def _model(scene, pts, links, groups, joints):
    """A registered model whose link k is the true surface samples of the true links in
    groups[k]; joints: (type, axis, point, parent, child, motion, name). Also returns the link
    map (sim.evaluate.link_correspondence) and the model's and true labels of its points."""
    masks = [np.isin(links, g) for g in groups]
    model_links = [Link(points=pts[m], match_indices=np.full(int(m.sum()), -1), name=f"link_{k}")
                   for k, m in enumerate(masks)]
    js = [Joint(t, a, p, parent=pa, child=ch, state_a=0.0, state_b=mo, name=n)
          for t, a, p, pa, ch, mo, n in joints]
    model = ArticulatedModel(links=model_links, joints=js, scale=1.0, scale_known=True)
    labels_pred = np.concatenate([np.full(int(m.sum()), k) for k, m in enumerate(masks)])
    labels_true = evaluate.rigid_bodies(scene)[np.concatenate([links[m] for m in masks])]
    return model, evaluate.link_correspondence(labels_pred, labels_true), labels_pred, labels_true


def _truth(scene, name):
    j = scene.joint(name)
    return j.type, j.axis, j.point, j.motion


def test_rigid_bodies_merge_a_link_behind_a_static_joint():
    assert evaluate.rigid_bodies(load_scene("cabinet")).tolist() == [0, 1, 2]
    still = load_scene("cabinet_door_only")
    assert [li.name for li in still.links] == ["object", "cabinet_door", "cabinet_drawer"]
    assert evaluate.rigid_bodies(still).tolist() == [0, 1, 0]  # the shut drawer is the carcass
    assert [j.name for j in still.moving_joints] == ["door_hinge"]


def test_static_joint_is_reported_not_invented_and_its_link_scores_with_its_parent():
    scene = load_scene("cabinet_door_only")
    pts, links = _samples(scene)
    t, a, p, m = _truth(scene, "door_hinge")
    # two rigid bodies: carcass with the shut drawer (true links 0 and 2), and the door
    model, link_map, lp, lt = _model(scene, pts, links, [[0, 2], [1]],
                                     [(t, a, p, 0, 1, m, "door")])
    assert link_map == {0: 0, 1: 1}
    assert metrics.segmentation_accuracy(lp, lt) == pytest.approx(1.0)
    out = evaluate.score_joints(scene, model, link_map)
    (row,) = out["joints"]
    assert row["name"] == "door_hinge" and row["passes"] and row["paired_by_links"]
    assert out["static_joints"] == ["drawer_slide"] and out["invented_joints"] == []
    assert out["tree_correct"]
    # a model that splits the shut drawer off with a tiny "joint" invents it
    model, link_map, _, _ = _model(
        scene, pts, links, [[0], [1], [2]],
        [(t, a, p, 0, 1, m, "door"), ("prismatic", [1.0, 0, 0], [0.1, 0, 0.7], 0, 2, 0.002,
                                      "ghost")])
    out = evaluate.score_joints(scene, model, link_map)
    assert [g["name"] for g in out["invented_joints"]] == ["ghost"]
    assert out["joints"][0]["estimated_joint"] == "door" and not out["tree_correct"]


def test_chain_joints_pair_by_links_not_by_nearest_axis():
    """scraper_truck: boom (object -> boom) and blade (boom -> blade) hinges, both about -y.
    An estimate whose boom axis sits at the blade's hinge and vice versa is two wrong axes (by
    174 mm each), not two right ones swapped."""
    scene = load_scene("scraper_truck")
    pts, links = _samples(scene)
    tb, ab, pb, mb = _truth(scene, "boom_hinge")
    tl, al, pl, ml = _truth(scene, "blade_hinge")
    exact, link_map, _, _ = _model(scene, pts, links, [[0], [1], [2]],
                                   [(tb, ab, pb, 0, 1, mb, "e_boom"),
                                    (tl, al, pl, 1, 2, ml, "e_blade")])
    out = evaluate.score_joints(scene, exact, link_map)
    assert out["tree_correct"] and all(r["passes"] and r["paired_by_links"] for r in out["joints"])
    crossed = _model(scene, pts, links, [[0], [1], [2]],
                     [(tb, ab, pl, 0, 1, mb, "e_boom"), (tl, al, pb, 1, 2, ml, "e_blade")])[0]
    out = evaluate.score_joints(scene, crossed, link_map)
    rows = {r["name"]: r for r in out["joints"]}
    assert rows["boom_hinge"]["estimated_joint"] == "e_boom"
    assert rows["blade_hinge"]["estimated_joint"] == "e_blade"
    gap = 1e3 * np.linalg.norm(np.cross(pl - pb, ab))
    assert rows["boom_hinge"]["axis_position_mm"] == pytest.approx(gap, abs=1e-6)
    assert gap > 100 and not rows["boom_hinge"]["passes"]
    # without a link map (nothing to say which links a joint joins) the geometry decides
    out = evaluate.score_joints(scene, crossed)
    assert {r["name"]: r["estimated_joint"] for r in out["joints"]} == {
        "boom_hinge": "e_blade", "blade_hinge": "e_boom"}
    assert not out["tree_correct"]


def test_wrong_tree_is_reported():
    """The blade hung on the chassis instead of the boom: its motion relative to the chassis is
    the sum of both hinges (60 deg), the tree is wrong, and the blade joint fails its gates."""
    scene = load_scene("scraper_truck")
    pts, links = _samples(scene)
    tb, ab, pb, mb = _truth(scene, "boom_hinge")
    tl, al, pl, ml = _truth(scene, "blade_hinge")
    model, link_map, _, _ = _model(scene, pts, links, [[0], [1], [2]],
                                   [(tb, ab, pb, 0, 1, mb, "e_boom"),
                                    (tl, al, pl, 0, 2, mb + ml, "e_blade")])
    out = evaluate.score_joints(scene, model, link_map)
    rows = {r["name"]: r for r in out["joints"]}
    assert not out["tree_correct"]
    assert rows["boom_hinge"]["paired_by_links"] and rows["boom_hinge"]["passes"]
    assert not rows["blade_hinge"]["paired_by_links"]
    assert rows["blade_hinge"]["state_error"] == pytest.approx(np.rad2deg(mb), abs=1e-6)
    assert not rows["blade_hinge"]["passes"]


def test_cabinet_hinge_and_slide_pair_by_links():
    scene = load_scene("cabinet")
    pts, links = _samples(scene)
    td, ad, pd, md = _truth(scene, "door_hinge")
    ts, as_, ps, ms = _truth(scene, "drawer_slide")
    # the model's links in another order than the scene's: drawer, carcass, door
    model, link_map, _, _ = _model(scene, pts, links, [[2], [0], [1]],
                                   [(ts, as_, ps, 1, 0, ms, "e_slide"),
                                    (td, ad, pd, 1, 2, md, "e_door")])
    assert link_map == {0: 2, 1: 0, 2: 1}
    out = evaluate.score_joints(scene, model, link_map)
    assert out["tree_correct"] and out["invented_joints"] == []
    rows = {r["name"]: r for r in out["joints"]}
    assert rows["door_hinge"]["estimated_joint"] == "e_door" and rows["door_hinge"]["passes"]
    assert rows["drawer_slide"]["estimated_joint"] == "e_slide"
    assert rows["drawer_slide"]["passes"] and rows["drawer_slide"]["axis_position_mm"] is None


# ------------------------------------------------------------------------------ fast: the arm


def test_manipulation_welds_to_the_scenes_own_arm():
    """pliers_panda: the grasp welds join the Panda's flange (not the PUMA's, which the scene
    does not have) and visibility is judged through the Panda's wrist camera."""
    from sim import manipulate

    scene = load_scene("pliers_panda")
    world = manipulate.build_world(scene)
    assert world.kin.spec.name == "panda"
    assert world.model.body(world.flange_body).name == "panda_link7"
    data = manipulate.fresh_data(world)
    cands = manipulate.scene_grasp_candidates(world, data, scene.link("pliers_moving").body_ids)
    pw = manipulate.PlanningWorld.from_scene(world)
    out = pw.classify_visibility(data.qpos[world.qidx].copy(), cands)
    assert len(out) == len(cands) > 0


def test_short_links_still_have_grasp_candidates():
    """A Barrett finger reaches 4.7 cm from its spread axis, under min_lever (6 cm): its outer
    points are used; on a link that reaches farther the min_lever rule stands."""
    from sim import manipulate

    scene = load_scene("barrett_hand")
    world = manipulate.build_world(scene)
    data = manipulate.fresh_data(world)
    j = scene.joint("finger1_spread")
    est = manipulate.JointEstimate(j.type, j.axis, j.point, "ground truth", j.name)
    cands = manipulate.scene_grasp_candidates(world, data, scene.link("finger1").body_ids)
    cfg = manipulate.PlanningConfig()

    def lever(c):
        v = c.point - j.point
        return float(np.linalg.norm(v - (v @ j.axis) * j.axis))

    reach = max(lever(c) for c in cands)
    assert reach < cfg.min_lever
    ranked = manipulate.rank(cands, est, prefer_hidden=True)
    assert ranked and all(lever(c) >= cfg.min_lever_fraction * reach for c in ranked)
    far = [manipulate.GraspCandidate(j.point + [0.08, 0.0, 0.0], np.array([1.0, 0, 0]))]
    ranked = manipulate.rank(cands + far, est, prefer_hidden=True)
    assert [c.point.tolist() for c in ranked] == [far[0].point.tolist()]


def _door_static(scene):
    """cabinet with the door left shut and the drawer moved: a scene whose FIRST joint is static
    (the bundled cabinet_door_only has it the other way round)."""
    import dataclasses

    door = scene.joint("door_hinge")
    joints = tuple(dataclasses.replace(j, value_b=j.value_a) if j is door else j
                   for j in scene.joints)
    return dataclasses.replace(scene, joints=joints)


def test_the_demonstration_follows_a_joint_that_moved():
    """Without a model (a demonstration along the true joint), sim.manipulate's default joint is
    the first that moved, not a static first one."""
    from sim import manipulate

    scene = _door_static(load_scene("cabinet"))
    assert [j.name for j in scene.moving_joints] == ["drawer_slide"]
    assert manipulate.default_joint(scene).name == "drawer_slide"
    assert manipulate.joint_estimate_from_scene(scene).name == "drawer_slide"
    assert manipulate.default_joint(load_scene("cabinet_door_only")).name == "door_hinge"
    assert manipulate.default_joint(load_scene("cabinet")).name == "door_hinge"


def _fake_run(model, k, achieved_m):
    j = model.joints[k]
    return {"requested": float(j.motion), "peak_force": 1.0, "rms_force": 0.5,
            "peak_torque": 0.1, "grip_limits": {"force_n": 60.0, "torque_nm": 3.0},
            "tracking_max_deg": 0.0, "path_error_max_mm": 0.0, "grasp_point": [0, 0, 0],
            "grasp_normal": [0, 0, 1], "grasp_hidden": True, "grasp_visibility": "hidden",
            "grasp_body": "cabinet_drawer", "grasp_lost": False, "grasp_lost_at": None,
            "planned_in": "registered model", "arm_contacts": [],
            "estimate": {"type": j.type, "axis": j.axis_direction.tolist(),
                         "point": j.axis_point.tolist(), "name": j.name},
            "joints_before": {"door_hinge": 0.0, "drawer_slide": 0.0},
            "joints_after": {"door_hinge": 0.0, "drawer_slide": achieved_m}}


def test_every_joint_of_the_model_is_moved_and_scored_against_its_true_joint(monkeypatch):
    """The robot moves the model's joints (every one, in turn), chosen from the model alone;
    scoring then pairs each with the true joint it estimates. The drawer of a cabinet whose door
    stayed shut: one model joint, one run, scored on drawer_slide; a run that stops short
    fails; a model joint that estimates no true joint fails."""
    scene = _door_static(load_scene("cabinet"))
    pts, links = _samples(scene)
    t, a, p, m = _truth(scene, "drawer_slide")
    model, link_map, _, _ = _model(scene, pts, links, [[0, 1], [2]],
                                   [(t, a, p, 0, 1, m, "e_slide")])
    out = evaluate.score_joints(scene, model, link_map)
    assert out["static_joints"] == ["door_hinge"]
    calls = []

    def stage(scene_, registered, idx, *args, **kw):
        calls.append(idx)
        return _fake_run(registered, idx, achieved[0]), {"build_s": 0.0}, False

    def reference(*args, **kw):
        return {"peak_force": 1.0}, {}, False

    monkeypatch.setattr(evaluate.runner, "manipulation_stage", stage)
    monkeypatch.setattr(evaluate.runner, "manipulation_reference_stage", reference)
    achieved = [m]
    result = {"joints": out["joints"], "cached_stages": []}
    man = evaluate.runner._manipulations(scene, model, result, None, [], evaluate.EvalConfig(),
                                         None, "")
    assert calls == [0]
    (run,) = man["runs"]
    assert run["true_joint"] == "drawer_slide" and run["passes"] and man["passes"]
    assert run["relative_error"] == pytest.approx(0.0)
    # 10% short of the request: fails the manipulation gate
    achieved[0] = 0.9 * m
    man = evaluate.runner._manipulations(scene, model, result, None, [], evaluate.EvalConfig(),
                                         None, "")
    assert not man["passes"]
    checks = gates.manipulation_checks(man)
    assert [c.gate for c in checks if not c.passed] == ["manipulation_relative_error"]
    # a joint of the model that estimates no true joint
    man = evaluate.runner._manipulations(scene, model, {"joints": [], "cached_stages": []},
                                         None, [], None, None, "")
    assert not man["passes"] and man["runs"][0]["true_joint"] is None
    # a joint already moved elsewhere (the scene's second process) is scored, not moved again
    calls.clear()
    done = evaluate.runner.manipulation_runs([0], scene, model, None, [], None, None, "")
    assert calls == [0] and done[0][1] is False
    result = {"joints": out["joints"], "cached_stages": []}
    moved = Future()
    moved.set_result({0: (done[0][0], True)})
    man = evaluate.runner._manipulations(scene, model, result, None, [], None, None, "",
                                         ([0], moved))
    assert calls == [0] and man["runs"][0]["true_joint"] == "drawer_slide"
    assert result["cached_stages"] == ["manipulation[e_slide]"]


def test_this_process_moves_its_joints_before_it_waits_for_the_other(monkeypatch):
    """With a second process moving some of the model's joints, this one moves the rest first
    and only then waits for the other's runs (waiting first left a core idle: cabinet's tail
    8.7 s door, then 5 s drawer); every joint's run is scored once, in the model's order."""
    scene = load_scene("cabinet")
    pts, links = _samples(scene)
    door, slide = _truth(scene, "door_hinge"), _truth(scene, "drawer_slide")
    model, _, _, _ = _model(scene, pts, links, [[0], [1], [2]],
                            [(*door[:3], 0, 1, door[3], "e_door"),
                             (*slide[:3], 0, 2, slide[3], "e_slide")])
    events = []

    def stage(scene_, registered, idx, *args, **kw):
        events.append(idx)
        return _fake_run(registered, idx, slide[3]), {"build_s": 0.0}, False

    class Elsewhere(Future):
        def result(self, timeout=None):
            events.append("waited")
            return super().result(timeout)

    monkeypatch.setattr(evaluate.runner, "manipulation_stage", stage)
    theirs = Elsewhere()
    theirs.set_result({0: (_fake_run(model, 0, slide[3]), False)})
    man = evaluate.runner._manipulations(scene, model, {"joints": [], "cached_stages": []},
                                         None, [], None, None, "", ([0], theirs))
    assert events == [1, "waited"]
    assert [r["model_joint"] for r in man["runs"]] == ["e_door", "e_slide"]


def test_the_force_reference_replays_the_runs_grasp_and_arm(monkeypatch, tmp_path):
    """The force reference replays the manipulation's grasp (point, normal, roll, the arm's
    configurations from pre-grasp to grasp, the run's start) along the true joint and along
    the two joints made as wrong as the gates allow; it plans nothing again in the true scene.
    Replanned (with seed 0, then with the run's seed), it had found 'grasp pose unreachable'
    for grasps the run had reached, or refused them on the true scene's contacts, and the force
    limit fell to the 2 N floor (benchmarks/bench_gates.py at 863fc30)."""
    from sim import manipulate as manip_pkg
    from sim.evaluate import scoring

    scene = load_scene("drawer")
    calls = []

    def fake_replay(scene_, est, amount, run_, *, q_start=None, **kw):
        calls.append((est.source, amount, run_, list(q_start)))
        raise manip_pkg.ManipulationError("recorded")

    def no_plan(*args, **kw):
        raise AssertionError("the force reference planned again")

    monkeypatch.setattr(manip_pkg, "replay", fake_replay)
    monkeypatch.setattr(manip_pkg, "manipulate", no_plan)
    (tj,) = [j for j in scene.joints if j.type == "prismatic"]
    approach = [[0.1 * k] * 7 for k in range(3)]
    run = {"estimate": {"axis": list(-np.asarray(tj.axis))}, "requested": 0.1,
           "grasp_point": [0.0, 0.0, 0.5], "grasp_normal": [0.0, 0.0, 1.0],
           "grasp_roll_deg": 90.0, "approach": approach, "q_start": [0.3] * 7}
    ref, _, _ = scoring.manipulation_reference_stage(scene, tj.name, run, [0.3] * 7, tmp_path,
                                                     "hash")
    assert len(calls) == 3  # the true joint and the two made as wrong as the gates allow
    assert calls[0][0] == "ground truth (force reference)"
    assert all(amount == pytest.approx(-0.1) for _, amount, _, _ in calls)  # the run's sense
    for _, _, grasp, q in calls:
        assert grasp["approach"] == approach and grasp["grasp_roll_deg"] == 90.0
        assert grasp["grasp_point"] == run["grasp_point"] and q == [0.3] * 7
    assert "recorded" in ref["error"]
