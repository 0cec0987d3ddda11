"""The scenes of the method's wider object set (issue 10): scissors, barrett_hand, scraper_truck
and cabinet. tests/test_scenes.py already checks every scene file (compiles, a second of physics
without warnings, configurations hold, ground truth against the XML, textures); here: each scene's
kinematic tree and joint types are the ones it is meant to show, coupled joints stay coupled,
parts do not interpenetrate, moving links can be pushed, and sim.scene reports a joint that does
not move between the configurations as static, and rejects configurations that break a coupling.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim.scene import SceneError, load_scene

#: scene -> {joint: (type, parent link, child link)}: the tree each scene is meant to show.
EXPECTED_TREES = {
    "scissors": {"scissors_hinge": ("revolute", "object", "scissors_moving")},
    "barrett_hand": {"finger1_spread": ("revolute", "object", "finger1"),
                     "finger2_spread": ("revolute", "object", "finger2")},
    "scraper_truck": {"boom_hinge": ("revolute", "object", "scraper_boom"),
                      "blade_hinge": ("revolute", "scraper_boom", "scraper_blade")},
    "cabinet": {"door_hinge": ("revolute", "object", "cabinet_door"),
                "drawer_slide": ("prismatic", "object", "cabinet_drawer")},
}
#: Largest overall size of each object (m), from the issue's real sizes (scissors ~18 cm).
EXPECTED_SIZE = {"scissors": (0.17, 0.19), "barrett_hand": (0.10, 0.16),
                 "scraper_truck": (0.28, 0.34), "cabinet": (0.28, 0.34)}
#: Parent and child links overlap only at the joint (a clevis around a hinge pin): within this
#: distance of the joint's axis. Elsewhere, and between links that share no joint, collision
#: geoms must stay apart (a small slack for touching faces).
JOINT_OVERLAP_RADIUS = 0.025
CONTACT_SLACK = 1e-4


@pytest.mark.parametrize("name", sorted(EXPECTED_TREES))
def test_tree_and_joint_types(name):
    scene = load_scene(name)
    got = {j.name: (j.type, j.parent, j.child) for j in scene.joints}
    assert got == EXPECTED_TREES[name]
    assert all(not j.static for j in scene.joints), "every joint of these scenes moves"
    assert scene.moving_joints == scene.joints


@pytest.mark.parametrize("name", sorted(EXPECTED_TREES))
def test_object_has_real_size(name):
    scene = load_scene(name)
    data = scene.make_data("a")
    bodies = {b for li in scene.links for b in li.body_ids}
    pts = []
    for g in range(scene.model.ngeom):
        if int(scene.model.geom_bodyid[g]) in bodies and scene.model.geom_type[g] == \
                mujoco.mjtGeom.mjGEOM_MESH:
            m = int(scene.model.geom_dataid[g])
            v = scene.model.mesh_vert[scene.model.mesh_vertadr[m]:
                                      scene.model.mesh_vertadr[m] + scene.model.mesh_vertnum[m]]
            R = data.geom_xmat[g].reshape(3, 3)
            pts.append(v @ R.T + data.geom_xpos[g])
    pts = np.concatenate(pts)
    size = float(np.max(pts.max(0) - pts.min(0)))
    lo, hi = EXPECTED_SIZE[name]
    assert lo <= size <= hi, f"{name}: {size * 100:.1f} cm"
    assert pts[:, 2].min() >= 0.45 - 1e-9, "nothing below the table top"


def _link_of_geoms(scene):
    link = {}
    for li in scene.links:
        for b in li.body_ids:
            link[b] = li.name
    return {g: link[int(scene.model.geom_bodyid[g])] for g in range(scene.model.ngeom)
            if int(scene.model.geom_bodyid[g]) in link and scene.model.geom_group[g] == 3}


@pytest.mark.parametrize("name", sorted(EXPECTED_TREES))
@pytest.mark.parametrize("configuration", ["a", "b"])
def test_links_do_not_interpenetrate(name, configuration):
    """Contacts between the object's links are excluded (the joints guide them), so check the
    geometry here: no two links overlap except parent and child around their joint's axis."""
    scene = load_scene(name)
    model = scene.model
    data = scene.make_data(configuration)
    geoms = _link_of_geoms(scene)
    joints = {(j.parent, j.child): j for j in scene.joints}
    fromto = np.zeros(6)
    # the joint's axis in configuration ``configuration``: its anchor and direction from MuJoCo
    for g1 in geoms:
        for g2 in geoms:
            if g2 <= g1 or geoms[g1] == geoms[g2]:
                continue
            d = mujoco.mj_geomDistance(model, data, g1, g2, 0.05, fromto)
            if d > -CONTACT_SLACK:
                continue
            j = joints.get((geoms[g1], geoms[g2])) or joints.get((geoms[g2], geoms[g1]))
            pair = (model.geom(g1).name, model.geom(g2).name)
            assert j is not None, f"{name}/{configuration}: {pair} overlap by {-d * 1e3:.1f} mm"
            anchor, axis = data.xanchor[j.joint_id], data.xaxis[j.joint_id]
            mid = (fromto[:3] + fromto[3:]) / 2
            r = mid - anchor
            off_axis = np.linalg.norm(r - np.dot(r, axis) * axis)
            assert j.type == "revolute" and off_axis < JOINT_OVERLAP_RADIUS, \
                f"{name}/{configuration}: {pair} overlap {off_axis * 1e3:.0f} mm from {j.name}"


@pytest.mark.parametrize("name", sorted(EXPECTED_TREES))
def test_moving_links_have_mass_and_collision_geoms(name):
    """The arm moves a link by contact: each moving link needs collision geoms and mass."""
    scene = load_scene(name)
    geoms = _link_of_geoms(scene)
    for li in scene.links[1:]:
        assert sum(1 for v in geoms.values() if v == li.name) >= 1
        mass = sum(float(scene.model.body_mass[b]) for b in li.body_ids)
        assert mass > 0.02, f"{li.name}: {mass * 1e3:.0f} g"


def test_barrett_fingers_are_coupled_and_mirror_images():
    scene = load_scene("barrett_hand")
    (c,) = scene.couplings
    assert {c.joint1, c.joint2} == {"finger1_spread", "finger2_spread"}
    f1, f2 = scene.joint("finger1_spread"), scene.joint("finger2_spread")
    mirror = np.diag([1.0, -1.0, 1.0])  # the xz plane through the palm's centre
    # A mirror flips an axis' handedness: the mirror of f1's rotation is a rotation about -M a1.
    np.testing.assert_allclose(f2.axis, -mirror @ f1.axis, atol=1e-12)
    np.testing.assert_allclose(f2.point, mirror @ f1.point, atol=1e-12)
    for config in "ab":
        poses = scene.link_poses(config)
        R1, R2 = poses["finger1"][:3, :3], poses["finger2"][:3, :3]
        np.testing.assert_allclose(R2, mirror @ R1 @ mirror, atol=1e-12)
    # The coupling holds under physics: push finger 1 and finger 2 follows.
    data = scene.make_data("a")
    data.qfrc_applied[f1.dof_adr] = 0.3  # N m: above both joints' friction (0.1 N m each)
    mujoco.mj_step(scene.model, data, nstep=100)  # 0.2 s
    q1, q2 = data.qpos[f1.qpos_adr], data.qpos[f2.qpos_adr]
    assert q1 > np.deg2rad(5), f"finger 1 did not turn ({np.rad2deg(q1):.2f} deg)"
    assert abs(q1 - q2) < np.deg2rad(0.5), f"{np.rad2deg(q1):.2f} vs {np.rad2deg(q2):.2f} deg"


# ------------------------------------------------------------------------------------------
# Static joints and broken couplings, on small standalone scenes
# ------------------------------------------------------------------------------------------

_TWO_JOINTS = """<mujoco>
  <compiler angle="radian" autolimits="true"/>
  <worldbody>
    <body name="object" pos="0 0 0.45">
      <geom type="box" size="0.05 0.05 0.02"/>
      <body name="lid" pos="0 0 0.03">
        <joint name="lid_hinge" axis="0 1 0" range="0 1"/>
        <geom type="box" size="0.05 0.05 0.01"/>
      </body>
      <body name="tray" pos="0 0 -0.01">
        <joint name="tray_slide" type="slide" axis="1 0 0" range="0 0.2"/>
        <geom type="box" size="0.04 0.04 0.005"/>
      </body>
    </body>
  </worldbody>
  {equality}
  <custom>{configs}</custom>
</mujoco>
"""


def _write(tmp_path: Path, configs: dict[str, tuple[float, float]], equality: str = "") -> Path:
    text = "".join(f'<numeric name="config_{c}:{j}" data="{v[i]!r}"/>'
                   for j, v in configs.items() for i, c in enumerate("ab"))
    path = tmp_path / "two_joints.xml"
    path.write_text(_TWO_JOINTS.format(configs=text, equality=equality))
    return path


def test_joint_that_does_not_move_is_static(tmp_path):
    scene = load_scene(_write(tmp_path, {"lid_hinge": (0.0, 0.5), "tray_slide": (0.05, 0.05)}))
    lid, tray = scene.joint("lid_hinge"), scene.joint("tray_slide")
    assert (lid.static, lid.motion) == (False, 0.5)
    assert (tray.static, tray.motion) == (True, 0.0)
    assert scene.moving_joints == (lid,)
    # The static joint's child does not move between the configurations; the other's does.
    pa, pb = scene.link_poses("a"), scene.link_poses("b")
    np.testing.assert_allclose(pb["tray"], pa["tray"], atol=1e-15)
    assert not np.allclose(pb["lid"], pa["lid"])


def test_configurations_must_satisfy_couplings(tmp_path):
    eq = ('<equality><joint name="c" joint1="tray_slide" joint2="lid_hinge" '
          'polycoef="0 0.1 0 0 0"/></equality>')
    scene = load_scene(_write(tmp_path, {"lid_hinge": (0.0, 0.5), "tray_slide": (0.0, 0.05)}, eq))
    assert scene.couplings[0].value(0.5) == pytest.approx(0.05)
    path = _write(tmp_path, {"lid_hinge": (0.0, 0.5), "tray_slide": (0.0, 0.08)}, eq)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    for needle in (str(path), '<equality><joint name="c">', "tray_slide = 0.05",
                   "configuration 'b'", "fix"):
        assert needle in message, f"{needle!r} not in {message!r}"
