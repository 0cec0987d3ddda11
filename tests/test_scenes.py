"""Scenes, in the style of MuJoCo Menagerie's tests: every scene compiles, steps a second of physics
without MuJoCo warnings, and its ground truth matches what its XML says (read here independently
with xml.etree). Malformed scenes raise SceneError naming file, element and fix. The generated
assets are checked: textures rich and non-repeating, UV regions disjoint, texel size fine enough,
and scenes/make_assets.py reproduces the committed files exactly."""

from __future__ import annotations

import importlib.util
import re
import shutil
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sim.scene import (
    BUNDLED_SCENES_DIR,
    HOLD_PREFIX,
    SCENES_DIR,
    STAGE_FILES,
    SceneError,
    hold_joints,
    list_scenes,
    load_scene,
    physics_warnings,
    release_joints,
    scene_path,
    stage_file,
)

BUNDLED = ("drawer", "pliers", "truck")
SCENES = list_scenes()
ASSETS = SCENES_DIR / "assets"

#: Object parts must show at least one texel per image pixel at the capture distance:
#: fx = 554 px at 0.4 m is 0.72 mm per pixel at the image centre, a 20 cm object filling half
#: the image 1.4 mm per pixel.
MAX_OBJECT_TEXEL = 1.4e-3
#: Tiles (texels) compared with each other, on the texture's detail (minus a Gaussian blur of
#: sigma DETAIL_SIGMA, so that two tiles inside smooth colour ramps do not look alike), and the
#: normalised cross-correlation above which two tiles are a repeat: a copy scores 1, distinct
#: 64-texel tiles of the generated textures score at most about 0.35.
TILE = 64
DETAIL_SIGMA = 8.0
MAX_TILE_CORRELATION = 0.7
#: Shifts (texels) beyond the size of the largest blob, where the detail of a non-repeating
#: texture no longer correlates with itself, and the highest autocorrelation allowed there
#: (a tiled texture reaches about 1 at its period).
MIN_REPEAT_SHIFT = 32
MAX_AUTOCORRELATION = 0.3
#: A blank tile (detail std below this many grey levels) is a surface without texture.
MIN_TILE_STD = 4.0
#: Drift allowed when a configuration is left to itself for a second (joint friction holds it).
HOLD_TOL = {"revolute": np.deg2rad(0.5), "prismatic": 1e-3}


def test_bundled_scenes_are_listed():
    assert set(BUNDLED) <= set(SCENES)
    assert "stage" not in SCENES


def test_scenes_readme_mentions_every_scene():
    text = (SCENES_DIR / "README.md").read_text()
    for name in SCENES:
        assert f"{name}.xml" in text, f"scenes/README.md does not describe {name}.xml"


# ------------------------------------------------------------------------------------------
# Compile and step
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SCENES)
@pytest.mark.parametrize("configuration", ["a", "b"])
def test_scene_steps_one_second_without_warnings(name, configuration):
    scene = load_scene(name)
    model = scene.model
    data = scene.make_data(configuration)
    mujoco.mj_step(model, data, nstep=int(round(1.0 / model.opt.timestep)))
    counts = {i: int(data.warning[i].number) for i in range(len(data.warning))}
    assert not any(counts.values()), f"{name}: MuJoCo warnings {counts}"
    assert physics_warnings(scene, 1.0, configuration) == {}
    assert np.all(np.isfinite(data.qpos))


@pytest.mark.parametrize("name", SCENES)
@pytest.mark.parametrize("configuration", ["a", "b"])
def test_configuration_holds_for_one_second(name, configuration):
    """Left alone, the object stays in its configuration (friction holds gravity loads)."""
    scene = load_scene(name)
    data = scene.make_data(configuration)
    mujoco.mj_step(scene.model, data, nstep=int(round(1.0 / scene.model.opt.timestep)))
    for j in scene.joints:
        drift = abs(data.qpos[j.qpos_adr] - j.value(configuration))
        assert drift < HOLD_TOL[j.type], f"{name}: {j.name} drifted by {drift:g}"


#: A held joint must stay this close to its value through a long capture (sim.capture's drift
#: tolerance is 1e-4 rad or m).
HELD_TOL = 2e-5


@pytest.mark.parametrize("name", SCENES)
def test_joint_holds_keep_the_configuration_where_friction_lets_it_creep(name):
    scene = load_scene(name)
    held = scene.with_joint_holds()
    model = held.model
    # same bodies, joints and geoms: ids and addresses of the scene stay valid
    assert (model.nq, model.nbody, model.ngeom) == (scene.model.nq, scene.model.nbody,
                                                   scene.model.ngeom)
    driven = {c.joint1 for c in scene.couplings}
    assert set(held.held_joints) == {j.name for j in scene.joints} - driven
    holds = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, HOLD_PREFIX + j)
             for j in held.held_joints]
    assert min(holds, default=0) >= 0
    for configuration in ("a", "b"):
        data = held.make_data(configuration)
        # inactive by default: the model steps as the scene does
        assert not data.eq_active[holds].any()
        free = scene.make_data(configuration)
        held.hold(data, configuration)
        steps = int(round(10.0 / model.opt.timestep))
        mujoco.mj_step(model, data, nstep=steps)
        mujoco.mj_step(scene.model, free, nstep=steps)
        for j in scene.joints:
            drift = abs(data.qpos[j.qpos_adr] - j.value(configuration))
            assert drift < HELD_TOL, f"{name}/{configuration}: held {j.name} moved by {drift:g}"
        assert not any(int(w.number) for w in data.warning)
    # a hold sits where it is told: hold the first joint at another value and it goes there
    if held.held_joints:
        j = scene.joint(held.held_joints[0])
        target = j.value_a + 0.25 * (j.range[1] - j.range[0]) * (1 if j.value_a < j.range.mean()
                                                                  else -1)
        data = held.make_data("a")
        hold_joints(model, data, {j.name: target})
        mujoco.mj_step(model, data, nstep=int(round(2.0 / model.opt.timestep)))
        assert abs(data.qpos[j.qpos_adr] - target) < HELD_TOL
        # released: its hold is off again
        release_joints(model, data)
        assert not data.eq_active[holds].any()


def test_a_loaded_hinge_creeps_without_its_hold():
    """Why the holds exist: the truck's tipped bed creeps under gravity against its friction."""
    scene = load_scene("truck")
    data = scene.make_data("b")
    mujoco.mj_step(scene.model, data, nstep=int(round(10.0 / scene.model.opt.timestep)))
    j = scene.joint("truck_bed_hinge")
    assert abs(data.qpos[j.qpos_adr] - j.value_b) > 10 * HELD_TOL
    with pytest.raises(KeyError, match="no hold on joint"):
        hold_joints(scene.model, data, {j.name: j.value_b})


@pytest.mark.parametrize("name", SCENES)
@pytest.mark.parametrize("configuration", ["a", "b"])
def test_object_does_not_penetrate_anything(name, configuration):
    scene = load_scene(name)
    model = scene.model
    data = scene.make_data(configuration)
    mujoco.mj_collision(model, data)
    object_bodies = {b for li in scene.links for b in li.body_ids}
    for c in data.contact[: data.ncon]:
        bodies = {int(model.geom_bodyid[c.geom1]), int(model.geom_bodyid[c.geom2])}
        if bodies & object_bodies:
            names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
                     for g in (c.geom1, c.geom2)]
            assert c.dist > -1e-3, f"{name}: {names} penetrate by {-c.dist * 1000:.1f} mm"


# ------------------------------------------------------------------------------------------
# Ground truth against the XML, read independently
# ------------------------------------------------------------------------------------------


def _floats(text: str | None, default: str) -> np.ndarray:
    return np.array([float(v) for v in (text if text is not None else default).split()])


#: Orientation attributes of an MJCF frame (body, frame, geom, ...): MuJoCo accepts exactly one.
ORIENTATIONS = ("quat", "axisangle", "euler", "xyaxes", "zaxis")


def _compiler(path: Path) -> dict:
    """``angle`` and ``eulerseq`` of the scene's <compiler>, looked up in the file and the files
    it includes (the stage sets them for every scene); MuJoCo's defaults otherwise."""
    out = {"angle": "degree", "eulerseq": "xyz"}
    seen = set()

    def visit(p: Path):
        p = p.resolve()
        if p in seen or not p.is_file():
            return
        seen.add(p)
        root = ET.parse(p).getroot()
        for comp in root.iter("compiler"):
            out.update({k: comp.get(k) for k in ("angle", "eulerseq") if comp.get(k)})
        for inc in root.iter("include"):
            f = Path(inc.get("file"))
            visit(f if f.is_absolute() else (path.parent / f if (path.parent / f).is_file()
                                             else p.parent / f))

    visit(path)
    return out


def _rotation(el: ET.Element, compiler: dict) -> np.ndarray:
    """Rotation (3, 3) of an MJCF element from whichever orientation attribute it has, read as
    MuJoCo documents them (angles in the compiler's unit; euler in its eulerseq, lower case
    axes rotating with the frame, upper case fixed)."""
    given = [a for a in ORIENTATIONS if el.get(a) is not None]
    assert len(given) <= 1, f"{el.tag} {el.get('name')}: several orientations {given}"
    unit = np.pi / 180 if compiler["angle"] == "degree" else 1.0
    if not given:
        return np.eye(3)
    kind, v = given[0], _floats(el.get(given[0]), "")
    if kind == "quat":
        w, x, y, z = v
        return Rotation.from_quat([x, y, z, w]).as_matrix()
    if kind == "axisangle":
        return Rotation.from_rotvec(v[:3] / np.linalg.norm(v[:3]) * v[3] * unit).as_matrix()
    if kind == "euler":
        # one elementary rotation per letter: lower case about the rotating (current) axis,
        # post-multiplied; upper case about the fixed (parent) axis, pre-multiplied
        R = np.eye(3)
        for letter, a in zip(compiler["eulerseq"], v * unit, strict=True):
            r = Rotation.from_rotvec(np.eye(3)["xyz".index(letter.lower())] * a).as_matrix()
            R = R @ r if letter.islower() else r @ R
        return R
    if kind == "xyaxes":
        x = v[:3] / np.linalg.norm(v[:3])
        y = v[3:] - (v[3:] @ x) * x
        y /= np.linalg.norm(y)
        return np.c_[x, y, np.cross(x, y)]
    z = v / np.linalg.norm(v)  # zaxis: the smallest rotation taking (0, 0, 1) to z
    axis = np.cross([0.0, 0.0, 1.0], z)
    s, c = np.linalg.norm(axis), z[2]
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix()


def _body_transform(el: ET.Element, compiler: dict) -> np.ndarray:
    """T_parent_body of an MJCF body or frame from pos and any orientation form."""
    T = np.eye(4)
    T[:3, :3] = _rotation(el, compiler)
    T[:3, 3] = _floats(el.get("pos"), "0 0 0")
    return T


def _xml_ground_truth(path: Path) -> dict:
    """Joints of the object from the XML alone: type, world axis and anchor at config A,
    parent and child body, range, both configuration values."""
    root = ET.parse(path).getroot()
    compiler = _compiler(path)
    configs = {}
    for num in root.iter("numeric"):
        m = re.fullmatch(r"config_([ab]):(.+)", num.get("name", ""))
        if m:
            configs[(m.group(1), m.group(2))] = float(num.get("data"))
    obj = next(b for b in root.iter("body") if b.get("name") == "object")
    out = {}

    def walk(body: ET.Element, T_world_parent: np.ndarray, parent_name: str, link: str):
        T = T_world_parent @ _body_transform(body, compiler)
        if body.tag == "frame":  # a frame only places what it holds
            for child in body:
                if child.tag in ("body", "frame"):
                    walk(child, T, parent_name, link)
            return
        joints = body.findall("joint")
        this_link = body.get("name") if joints else link
        for jel in joints:
            name = jel.get("name")
            axis = _floats(jel.get("axis"), "0 0 1")
            pos = _floats(jel.get("pos"), "0 0 0")
            jtype = jel.get("type", "hinge")
            rng = _floats(jel.get("range"), "nan nan")
            if jtype == "hinge" and compiler["angle"] == "degree":
                rng = np.deg2rad(rng)
            out[name] = dict(
                type={"hinge": "revolute", "slide": "prismatic"}[jtype],
                axis=T[:3, :3] @ axis / np.linalg.norm(axis), point=T[:3, :3] @ pos + T[:3, 3],
                parent=link, child=this_link, range=rng,
                a=configs[("a", name)], b=configs[("b", name)])
            # Descendants see this joint at its configuration-A value.
            q = configs[("a", name)]
            M = np.eye(4)
            if jtype == "hinge":
                R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * q).as_matrix()
                M[:3, :3] = R
                M[:3, 3] = pos - R @ pos
            else:
                M[:3, 3] = axis / np.linalg.norm(axis) * q
            T = T @ M
        for child in body:
            if child.tag in ("body", "frame"):
                walk(child, T, body.get("name"), this_link)

    walk(obj, np.eye(4), "world", "object")
    return out


@pytest.mark.parametrize("name", SCENES)
def test_ground_truth_matches_xml(name):
    scene = load_scene(name)
    expected = _xml_ground_truth(scene.path)
    assert sorted(j.name for j in scene.joints) == sorted(expected)
    assert len(scene.joints) >= 1
    for j in scene.joints:
        e = expected[j.name]
        assert j.type == e["type"]
        np.testing.assert_allclose(j.axis, e["axis"], atol=1e-9)
        np.testing.assert_allclose(j.point, e["point"], atol=1e-9)
        assert (j.parent, j.child) == (e["parent"], e["child"])
        np.testing.assert_allclose(j.range, e["range"], atol=1e-12)
        assert (j.value_a, j.value_b) == (e["a"], e["b"])
    assert scene.links[0].name == "object"
    assert {li.name for li in scene.links} == {"object"} | {j.child for j in scene.joints}


#: A scene whose bodies use every orientation form MuJoCo accepts (and a <frame>), in the
#: compiler's angle unit; configurations are radians and metres whatever that unit.
_ORIENTED = """<mujoco>
  <compiler angle="{angle}" eulerseq="{seq}" autolimits="true"/>
  <worldbody>
    <body name="object" pos="0 0 0.45" euler="{e0} {e1} {e2}">
      <geom type="box" size="0.05 0.05 0.02"/>
      <body name="turned" pos="0.01 0.02 0.03" axisangle="1 2 3 {a1}">
        <joint name="j_hinge" type="hinge" axis="0 1 0.2" pos="0.01 0 0.02" range="{r0} {r1}"/>
        <geom type="box" size="0.01 0.01 0.01"/>
        <body name="welded" pos="0.02 0 0" xyaxes="1 1 0 -1 1 0.3">
          <geom type="box" size="0.01 0.01 0.01"/>
          <body name="slider" pos="0 0.01 0.02" zaxis="0.3 -0.2 1">
            <joint name="j_slide" type="slide" axis="1 0.5 0" pos="0 0 0.01" range="0 0.1"/>
            <geom type="box" size="0.01 0.01 0.01"/>
            <frame pos="0 0.01 0" euler="{e2} {e0} {e1}">
              <body name="last" pos="0.01 0 0" quat="0.9 0.1 -0.3 0.2">
                <joint name="j_last" type="hinge" axis="1 0 0" range="{r0} {r1}"/>
                <geom type="box" size="0.01 0.01 0.01"/>
              </body>
            </frame>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <custom>
    <numeric name="config_a:j_hinge" data="0.3"/>
    <numeric name="config_b:j_hinge" data="0.8"/>
    <numeric name="config_a:j_slide" data="0.02"/>
    <numeric name="config_b:j_slide" data="0.1"/>
    <numeric name="config_a:j_last" data="-0.4"/>
    <numeric name="config_b:j_last" data="0.1"/>
  </custom>
</mujoco>
"""


@pytest.mark.parametrize(("angle", "seq"), [("degree", "xyz"), ("degree", "XYZ"),
                                             ("radian", "zyx"), ("radian", "xYz")])
def test_every_orientation_form_is_read_as_mujoco_compiles_it(tmp_path, angle, seq):
    """quat, axisangle, euler (any eulerseq), xyaxes, zaxis and <frame>, in degrees or radians:
    the ground truth sim.scene reads from the compiled model equals the XML read here, and each
    body's orientation read here equals MuJoCo's."""
    deg = angle == "degree"
    k = 180 / np.pi if deg else 1.0
    path = tmp_path / "oriented.xml"
    path.write_text(_ORIENTED.format(angle=angle, seq=seq, e0=0.3 * k, e1=-0.5 * k, e2=1.1 * k,
                                     a1=0.7 * k, r0=-1.0 * k, r1=1.0 * k))
    scene = load_scene(path)
    expected = _xml_ground_truth(path)
    assert sorted(expected) == sorted(j.name for j in scene.joints)
    for j in scene.joints:
        e = expected[j.name]
        np.testing.assert_allclose(j.axis, e["axis"], atol=1e-9)
        np.testing.assert_allclose(j.point, e["point"], atol=1e-9)
        np.testing.assert_allclose(j.range, e["range"], atol=1e-9)
        assert (j.parent, j.child) == (e["parent"], e["child"])
    # body by body, at qpos0: world rotation read from the XML against MuJoCo's xmat
    model = scene.model
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    compiler = _compiler(path)
    root = ET.parse(path).getroot()

    def walk(el, R):
        R = R @ _rotation(el, compiler)
        if el.tag == "body":
            b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, el.get("name"))
            np.testing.assert_allclose(data.xmat[b].reshape(3, 3), R, atol=1e-9,
                                       err_msg=el.get("name"))
        for child in el:
            if child.tag in ("body", "frame"):
                walk(child, R)

    walk(next(b for b in root.iter("body") if b.get("name") == "object"), np.eye(3))


@pytest.mark.parametrize("name", SCENES)
def test_motion_is_big_enough_and_moves_the_child_link(name):
    """Revolute 25-35 deg, prismatic 8-12 cm; the child link's pose relative to its parent link
    changes by exactly that (for a chain, e.g. scraper_truck, the parent moves too)."""
    scene = load_scene(name)
    pa, pb = scene.link_poses("a"), scene.link_poses("b")
    for j in scene.joints:
        # Motion of the child in its parent's frame, expressed in the world at configuration A
        # (where the joint's axis and point are given); a parent fixed to the world: identity.
        Pa = pa[j.parent] if j.parent in pa else np.eye(4)
        Pb = pb[j.parent] if j.parent in pb else np.eye(4)
        local = (np.linalg.inv(Pb) @ pb[j.child]) @ np.linalg.inv(np.linalg.inv(Pa) @ pa[j.child])
        T_rel = Pa @ local @ np.linalg.inv(Pa)
        if j.static:  # a joint a scene leaves still (cabinet_door_only): its child does not move
            np.testing.assert_allclose(T_rel, np.eye(4), atol=1e-12)
            continue
        if j.type == "revolute":
            assert np.deg2rad(25) <= abs(j.motion) <= np.deg2rad(35)
            rotvec = Rotation.from_matrix(T_rel[:3, :3]).as_rotvec()
            np.testing.assert_allclose(rotvec, j.axis * j.motion, atol=1e-9)
            # Points on the axis do not move.
            np.testing.assert_allclose(T_rel[:3, :3] @ j.point + T_rel[:3, 3], j.point,
                                       atol=1e-9)
        else:
            assert 0.08 <= abs(j.motion) <= 0.12
            np.testing.assert_allclose(T_rel[:3, :3], np.eye(3), atol=1e-12)
            np.testing.assert_allclose(T_rel[:3, 3], j.axis * j.motion, atol=1e-9)


@pytest.mark.parametrize("name", SCENES)
def test_object_sits_on_the_table_centre(name):
    scene = load_scene(name)
    data = scene.make_data("a")
    np.testing.assert_allclose(data.xpos[scene.links[0].body_id], [0, 0, 0.45], atol=1e-12)


def test_set_configuration_and_load_by_path():
    scene = load_scene("pliers")
    same = load_scene(scene_path("pliers"))
    assert same.path == scene.path and same.joints[0].name == scene.joints[0].name
    data = scene.make_data("a")
    j = scene.joints[0]
    scene.set_configuration(data, "b")
    assert data.qpos[j.qpos_adr] == j.value_b
    scene.set_configuration(data, "a")
    np.testing.assert_allclose(data.xanchor[j.joint_id], j.point, atol=1e-12)
    with pytest.raises(ValueError, match="configuration"):
        scene.set_configuration(data, "c")
    other = mujoco.MjData(mujoco.MjModel.from_xml_string("<mujoco/>"))
    with pytest.raises(ValueError, match="qpos of shape"):
        scene.set_configuration(other, "a")


# ------------------------------------------------------------------------------------------
# Malformed scenes
# ------------------------------------------------------------------------------------------

_GOOD_OBJECT = """
    <body name="object" pos="0 0 0.45">
      <geom type="box" size="0.05 0.05 0.02"/>
      <body name="lid" pos="0 0 0.03">
        <joint name="lid_hinge" type="{jtype}" axis="0 1 0" {range}/>
        <geom type="box" size="0.05 0.05 0.01"/>
      </body>
    </body>"""


_CONFIGS = ('<numeric name="config_a:lid_hinge" data="0"/>'
            '<numeric name="config_b:lid_hinge" data="0.5"/>')


def _write(tmp_path: Path, *, obj: str | None = None, jtype: str = "hinge",
           range_: str = 'range="0 1"', configs: str | None = None, asset: str = "") -> Path:
    obj = _GOOD_OBJECT.format(jtype=jtype, range=range_) if obj is None else obj
    if configs is None:
        configs = _CONFIGS
    path = tmp_path / "broken.xml"
    path.write_text(f"""<mujoco>
  <compiler angle="radian" autolimits="true"/>
  <asset>{asset}</asset>
  <worldbody>{obj}
  </worldbody>
  <custom>{configs}</custom>
</mujoco>
""")
    return path


def test_minimal_standalone_scene_loads(tmp_path):
    scene = load_scene(_write(tmp_path))
    assert scene.reconstruct_settings == {}
    (j,) = scene.joints
    assert (j.type, j.parent, j.child, j.value_a, j.value_b) == ("revolute", "object", "lid",
                                                                  0.0, 0.5)
    np.testing.assert_allclose(j.point, [0, 0, 0.48], atol=1e-12)
    np.testing.assert_allclose(j.axis, [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("case, kwargs, needles", [
    ("no object", dict(obj='<body name="thing"><geom size="0.1"/></body>', configs=""),
     ['no body named "object"', 'name="object"']),
    ("ball joint", dict(jtype="ball", range_=""),
     ['<joint name="lid_hinge">', "ball joint", 'type="hinge"']),
    ("free joint", dict(obj='<body name="object" pos="0 0 0.45"><freejoint name="f"/>'
                            '<geom size="0.1"/></body>', configs=""),
     ['<joint name="f">', "free joint", 'type="slide"']),
    ("unknown joint", dict(configs='<numeric name="config_a:lid_hinge" data="0"/>'
                                   '<numeric name="config_b:lid_hinge" data="0.5"/>'
                                   '<numeric name="config_b:nothing" data="0"/>'),
     ['<numeric name="config_b:nothing">', "unknown joint 'nothing'", "lid_hinge"]),
    ("out of range", dict(configs='<numeric name="config_a:lid_hinge" data="0"/>'
                                  '<numeric name="config_b:lid_hinge" data="1.5"/>'),
     ['<numeric name="config_b:lid_hinge">', "outside the range [0, 1]", "inside the range"]),
    ("missing config", dict(configs='<numeric name="config_a:lid_hinge" data="0"/>'),
     ["'lid_hinge' has no value in configuration 'b'", 'name="config_b:lid_hinge"']),
    ("bad config name", dict(configs='<numeric name="config_c:lid_hinge" data="0"/>'),
     ['<numeric name="config_c:lid_hinge">', "config_a:<joint name>"]),
    ("unknown setting", dict(configs=_CONFIGS + '<numeric name="reconstruct:dense.nope" '
                                                'data="1"/>'),
     ["reconstruction setting 'dense.nope'", "no field 'nope'", "downsample",
      "reconstruct:STAGE.FIELD"]),
    ("bad setting value", dict(configs=_CONFIGS + '<numeric name="reconstruct:dense.downsample" '
                                                  'data="0.5"/>'),
     ['<numeric name="reconstruct:dense.downsample"', "not a whole number", "[1, 8]"]),
    ("setting out of range", dict(configs=_CONFIGS + '<numeric '
                                  'name="reconstruct:dense.downsample" data="0"/>'),
     ['<numeric name="reconstruct:dense.downsample"', "out of range", "[1, 8]",
      "1 full resolution"]),
    ("no range", dict(range_=""), ['<joint name="lid_hinge">', "no range", 'range="LO HI"']),
    ("missing texture", dict(asset='<texture name="t" type="2d" file="no_such_texture.png"/>'),
     ["no_such_texture.png", "could not compile", "relative to the scene file's folder"]),
    ("missing mesh", dict(asset='<mesh name="m" file="no_such_mesh.obj"/>'),
     ["no_such_mesh.obj", "could not compile", "make_assets.py"]),
])
def test_malformed_scene_raises_useful_error(tmp_path, case, kwargs, needles):
    path = _write(tmp_path, **kwargs)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    assert str(path) in message, f"{case}: message does not name the file: {message}"
    assert "fix" in message.lower(), f"{case}: message gives no fix: {message}"
    for needle in needles:
        assert needle in message, f"{case}: {needle!r} not in {message!r}"


def test_scene_reconstruction_settings_are_read_and_applied(tmp_path):
    """A scene's reconstruct:STAGE.FIELD numerics reach ReconstructConfig (sim.evaluate builds its
    config from them); scissors and both pliers scenes ask for full-resolution stereo (their
    halves are millimetres thick), scissors also for every image as a stereo reference (a
    boolean, given as 0), truck for nothing."""
    from artrecon.reconstruct import ReconstructConfig, with_settings

    path = _write(tmp_path, configs=_CONFIGS + '<numeric name="reconstruct:dense.downsample" '
                                               'data="1"/><numeric name="reconstruct:'
                                               'segmentation.min_link_fraction" data="0.05"/>')
    scene = load_scene(path)
    assert scene.reconstruct_settings == {"dense.downsample": 1.0,
                                          "segmentation.min_link_fraction": 0.05}
    config = with_settings(ReconstructConfig(), scene.reconstruct_settings)
    assert config.dense.downsample == 1 and isinstance(config.dense.downsample, int)
    assert config.segmentation.min_link_fraction == 0.05
    assert config.dense.voxel_pixels == ReconstructConfig().dense.voxel_pixels  # others kept
    assert load_scene("scissors").reconstruct_settings == {"dense.downsample": 1.0,
                                                           "dense.pair_cover": 0.0}
    scissors = with_settings(ReconstructConfig(), load_scene("scissors").reconstruct_settings)
    assert scissors.dense.pair_cover is False and ReconstructConfig().dense.pair_cover is True
    for name in ("pliers", "pliers_panda"):
        assert load_scene(name).reconstruct_settings == {"dense.downsample": 1.0}
    assert load_scene("truck").reconstruct_settings == {}


# ------------------------------------------------------------------------------------------
# Paths: scenes open from any usual working directory, and scenes live anywhere
# ------------------------------------------------------------------------------------------

REPO = BUNDLED_SCENES_DIR.parent


@pytest.mark.parametrize(("cwd", "prefix"), [(".", "scenes/"), ("scenes", ""),
                                             ("tests", "../scenes/"), ("/", None)])
def test_every_bundled_scene_opens_in_plain_mujoco_by_relative_path(monkeypatch, cwd, prefix):
    """mujoco.MjModel.from_xml_path, MuJoCo's own loader, opens every bundled scene from the
    repository root, from scenes/ and from a folder beside it by a relative path, and from
    anywhere by the absolute path (the stage's <model file="../robots/..."> included from a
    relative scene path is looked up in scenes/robots, a link to ../robots)."""
    names = list_scenes(BUNDLED_SCENES_DIR)
    assert len(names) >= 9
    monkeypatch.chdir(REPO / cwd if cwd != "/" else Path("/"))
    for name in names:
        path = f"{prefix}{name}.xml" if prefix is not None else str(BUNDLED_SCENES_DIR /
                                                                  f"{name}.xml")
        model = mujoco.MjModel.from_xml_path(path)
        spec_model = mujoco.MjSpec.from_file(path).compile()
        assert model.nbody == spec_model.nbody == load_scene(name).model.nbody


def _copy_scene_elsewhere(name: str, folder: Path) -> Path:
    """A bundled scene in ``folder`` with only its own file and assets: the stage included by
    its absolute path, as a scene anywhere on disk writes it."""
    src = BUNDLED_SCENES_DIR / f"{name}.xml"
    text = src.read_text()
    (folder / "assets").mkdir(parents=True)
    for f in re.findall(r'file="(assets/[^"]+)"', text):
        shutil.copy(BUNDLED_SCENES_DIR / f, folder / f)
    stage = re.search(r'<include file="([^"]+)"/>', text).group(1)
    arm = {v: k for k, v in STAGE_FILES.items()}[stage]
    text = text.replace(f'<include file="{stage}"/>', f'<include file="{stage_file(arm)}"/>')
    path = folder / f"{name}.xml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", ["pliers", "pliers_panda"])
def test_a_scene_folder_elsewhere_needs_only_its_xml_and_assets(tmp_path, monkeypatch, name):
    from sim.robot import load_arm_kinematics

    path = _copy_scene_elsewhere(name, tmp_path / "my_scene")
    assert sorted(p.name for p in path.parent.iterdir()) == ["assets", f"{name}.xml"]
    scene, bundled = load_scene(path), load_scene(name)
    assert scene.path == path and scene.model.nbody == bundled.model.nbody
    assert [j.name for j in scene.joints] == [j.name for j in bundled.joints]
    np.testing.assert_array_equal(scene.joints[0].axis, bundled.joints[0].axis)
    assert load_arm_kinematics(scene.model).spec == load_arm_kinematics(bundled.model).spec
    assert physics_warnings(scene, 0.2) == {}
    # MuJoCo's own loader too, by a relative path from the folder's parent
    monkeypatch.chdir(tmp_path)
    assert mujoco.MjModel.from_xml_path(f"my_scene/{name}.xml").nbody == bundled.model.nbody


def test_a_scene_elsewhere_that_includes_a_missing_stage_is_told_where_the_stage_is(tmp_path):
    path = tmp_path / "pliers.xml"
    path.write_text((BUNDLED_SCENES_DIR / "pliers.xml").read_text())
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    assert "stage.xml" in message and str(stage_file()) in message and "<include" in message


def test_unknown_scene_name_lists_the_scenes():
    with pytest.raises(SceneError, match="pliers"):
        load_scene("no_such_scene")
    with pytest.raises(SceneError, match="no such scene file"):
        load_scene("/nonexistent/scene.xml")


# ------------------------------------------------------------------------------------------
# Assets
# ------------------------------------------------------------------------------------------


def _visible_object_and_stage_geoms(scene):
    """Geoms drawn by the renderer (groups 0-2) on the object, the table and the world."""
    model = scene.model
    keep = {0, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "table")}
    keep |= {b for li in scene.links for b in li.body_ids}
    return [g for g in range(model.ngeom)
            if int(model.geom_bodyid[g]) in keep and int(model.geom_group[g]) <= 2
            and model.geom_rgba[g, 3] > 0]


@pytest.mark.parametrize("name", SCENES)
def test_every_visible_surface_is_a_textured_uv_mesh(name):
    scene = load_scene(name)
    model = scene.model
    geoms = _visible_object_and_stage_geoms(scene)
    assert len(geoms) >= 4  # floor, walls, table, at least one object part
    for g in geoms:
        gname = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
        assert model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH, f"{gname} is not a mesh"
        mesh = int(model.geom_dataid[g])
        assert model.mesh_texcoordnum[mesh] > 0, f"{gname}: mesh has no texture coordinates"
        mat = int(model.geom_matid[g])
        assert mat >= 0 and model.mat_texid[mat, int(mujoco.mjtTextureRole.mjTEXROLE_RGB)] >= 0, \
            f"{gname}: no 2d texture"
        assert model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0


def _read_obj(path: Path):
    v, vt, faces = [], [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            v.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vt":
            vt.append([float(x) for x in parts[1:3]])
        elif parts[0] == "f":
            faces.append([[int(i) - 1 for i in p.split("/")[:2]] for p in parts[1:]])
    f = np.array(faces)
    return np.array(v), np.array(vt), f[:, :, 0], f[:, :, 1]


OBJS = sorted(ASSETS.glob("*.obj"))
PNGS = sorted(ASSETS.glob("*.png"))
OBJECT_PARTS = ("pliers_fixed", "pliers_moving", "truck_chassis", "truck_bed", "cabinet",
                "drawer", "scissors_fixed", "scissors_moving", "barrett_palm", "barrett_finger1",
                "barrett_finger2", "scraper_chassis", "scraper_boom", "scraper_blade",
                "hinged_cabinet", "hinged_cabinet_door", "hinged_cabinet_drawer")


@pytest.mark.parametrize("obj", OBJS, ids=lambda p: p.stem)
def test_uv_regions_are_disjoint_and_fine_enough(obj):
    """No texel is used by two triangles (a texture never repeats on a surface), and object
    parts get at least one texel per image pixel at the capture distance."""
    v, vt, fv, ft = _read_obj(obj)
    h, w = cv2.imread(str(obj.with_suffix(".png"))).shape[:2]
    uv = np.c_[vt[:, 0] * w, (1.0 - vt[:, 1]) * h]  # texel coordinates, rows from the top
    cover = np.zeros((h, w), np.int32)
    texel_sizes = []
    for tv, tt in zip(fv, ft, strict=True):
        a, b, c = uv[tt]
        area_uv = 0.5 * abs((b - a)[0] * (c - a)[1] - (b - a)[1] * (c - a)[0])
        area_3d = 0.5 * np.linalg.norm(np.cross(v[tv[1]] - v[tv[0]], v[tv[2]] - v[tv[0]]))
        texel_sizes.append(np.sqrt(area_3d / area_uv))
        lo = np.floor(np.min(uv[tt], 0)).astype(int)
        hi = np.ceil(np.max(uv[tt], 0)).astype(int)
        assert np.all(lo >= 0) and hi[0] <= w and hi[1] <= h, f"{obj.name}: UV outside atlas"
        xs, ys = np.meshgrid(np.arange(lo[0], hi[0]) + 0.5, np.arange(lo[1], hi[1]) + 0.5)
        p = np.stack([xs, ys], -1)
        d = (b - a)[0] * (c - a)[1] - (b - a)[1] * (c - a)[0]
        l1 = ((b - p)[..., 0] * (c - p)[..., 1] - (b - p)[..., 1] * (c - p)[..., 0]) / d
        l2 = ((c - p)[..., 0] * (a - p)[..., 1] - (c - p)[..., 1] * (a - p)[..., 0]) / d
        inside = (l1 > 1e-6) & (l2 > 1e-6) & (1 - l1 - l2 > 1e-6)
        cover[lo[1]:hi[1], lo[0]:hi[0]] += inside
    assert cover.max() <= 1, f"{obj.name}: {np.sum(cover > 1)} texels used twice"
    if obj.stem in OBJECT_PARTS:
        assert max(texel_sizes) <= MAX_OBJECT_TEXEL, \
            f"{obj.name}: texels of {max(texel_sizes) * 1000:.2f} mm"


@pytest.mark.parametrize("png", PNGS, ids=lambda p: p.stem)
def test_texture_is_rich_and_does_not_repeat(png):
    img = cv2.imread(str(png)).astype(np.float32)
    detail = img - cv2.GaussianBlur(img, (0, 0), DETAIL_SIGMA)
    t = TILE
    h, w = (s // t * t for s in img.shape[:2])
    tiles = detail[:h, :w].reshape(h // t, t, w // t, t, 3).transpose(0, 2, 1, 3, 4)
    tiles = tiles.reshape(-1, t * t * 3)
    tiles -= tiles.mean(1, keepdims=True)
    std = np.sqrt((tiles ** 2).mean(1))
    assert std.min() >= MIN_TILE_STD, f"{png.name}: a blank {t}x{t} tile (std {std.min():.1f})"
    unit = tiles / np.linalg.norm(tiles, axis=1, keepdims=True)
    corr = unit @ unit.T
    np.fill_diagonal(corr, 0.0)
    assert corr.max() < MAX_TILE_CORRELATION, f"{png.name}: repeated tiles ({corr.max():.3f})"
    # A repeat by any shift shows as a peak of the autocorrelation of the texture's detail.
    spectrum = np.fft.rfft2(detail.mean(-1))
    ac = np.fft.irfft2(np.abs(spectrum) ** 2, s=detail.shape[:2])
    ac /= ac[0, 0]
    dy = np.minimum(np.arange(ac.shape[0]), ac.shape[0] - np.arange(ac.shape[0]))[:, None]
    dx = np.minimum(np.arange(ac.shape[1]), ac.shape[1] - np.arange(ac.shape[1]))[None, :]
    far = np.hypot(dx, dy) > MIN_REPEAT_SHIFT
    assert ac[far].max() < MAX_AUTOCORRELATION, \
        f"{png.name}: the texture repeats (autocorrelation {ac[far].max():.2f})"


def _load_make_assets():
    spec = importlib.util.spec_from_file_location("make_assets", SCENES_DIR / "make_assets.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while it executes
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[spec.name]
    return module


#: Textures may differ by one grey level in a handful of pixels between machines: OpenCV
#: dispatches its cubic resize and anti-aliased drawing to the CPU's SIMD (AVX2 or AVX-512), and
#: the rounding differs (4 of 3.1 M values of cabinet.png by 1 on an AMD EPYC). Anything more is a
#: different texture.
TEXTURE_MAX_DIFFERENCE = 1
TEXTURE_MAX_DIFFERING_SHARE = 1e-4
#: Mesh numbers are written with 6 decimals; a last-digit rounding difference between machines
#: (numpy's SIMD trigonometry) is 1e-6 of a metre or of a texture coordinate.
OBJ_MAX_DIFFERENCE = 1.5e-6


def _obj_differences(new: str, old: str, name: str) -> None:
    """Assert two OBJ texts have the same lines and keywords, numbers within OBJ_MAX_DIFFERENCE."""
    a, b = new.splitlines(), old.splitlines()
    assert len(a) == len(b), f"{name}: {len(a)} lines, committed {len(b)}"
    for k, (la, lb) in enumerate(zip(a, b, strict=True)):
        if la == lb:
            continue
        ta, tb = la.split(), lb.split()
        assert len(ta) == len(tb) and ta[0] == tb[0] and ta[0] in ("v", "vt", "vn"), \
            f"{name} line {k + 1}: {la!r} != {lb!r}"
        diff = np.abs(np.array(ta[1:], float) - np.array(tb[1:], float)).max()
        assert diff <= OBJ_MAX_DIFFERENCE, f"{name} line {k + 1}: {la!r} != {lb!r}"


def test_make_assets_reproduces_the_committed_assets(tmp_path):
    make_assets = _load_make_assets()
    make_assets.generate(tmp_path)
    names = {p.name for p in tmp_path.iterdir()}
    assert names == {p.name for p in ASSETS.iterdir()}
    for p in sorted(tmp_path.iterdir()):
        committed = ASSETS / p.name
        if p.suffix == ".obj":
            _obj_differences(p.read_text(), committed.read_text(), p.name)
        else:
            new, old = cv2.imread(str(p)), cv2.imread(str(committed))
            assert new.shape == old.shape, f"{p.name}: {new.shape} != {old.shape}"
            diff = np.abs(new.astype(int) - old.astype(int))
            assert diff.max() <= TEXTURE_MAX_DIFFERENCE, f"{p.name} differs by {diff.max()}"
            assert (diff > 0).mean() <= TEXTURE_MAX_DIFFERING_SHARE, \
                f"{p.name}: {(diff > 0).mean():.2e} of its values differ"


def test_assets_are_small():
    # About 5 MB for the stage and the first three scenes, 3.2 MB for the four of issue 10
    # (scissors, barrett_hand, scraper_truck, cabinet); 10 MB keeps the checkout light.
    total = sum(p.stat().st_size for p in ASSETS.iterdir())
    assert total < 10e6, f"assets take {total / 1e6:.1f} MB"
