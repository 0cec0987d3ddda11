"""``python -m sim.author import`` (issue 24): objects brought as a PartNet-Mobility-style URDF
or as an MJCF become scenes of the harness in a folder anywhere on disk, with the joints, scale
and placement the source implies, every part textured, collisions, contact excludes,
configurations that hold; bad input gets a clear error and leaves nothing behind. The scenes'
full evaluation against the main job's gates is tests/test_author_gates.py (slow)."""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import cv2
import mujoco
import numpy as np
import pytest
from author_objects import (
    CABINET_HINGE_AXIS,
    CABINET_HINGE_POINT,
    CABINET_MM,
    CHEST_CARCASS,
    CHEST_DRAWER,
    CHEST_HINGE_AXIS,
    CHEST_HINGE_POINT,
    CHEST_LID,
    CHEST_SLIDE_AXIS,
    DOOR_MM,
    write_mjcf_cabinet,
    write_partnet_chest,
)

from sim import cache
from sim.author import AuthorError, ImportConfig, import_object
from sim.author.__main__ import main as author_main
from sim.scene import BUNDLED_SCENES_DIR, load_scene, physics_warnings

REPO = BUNDLED_SCENES_DIR.resolve().parent

#: Drift allowed over a second left alone (as tests/test_scenes.py demands of every scene).
HOLD_TOL = {"revolute": np.deg2rad(0.5), "prismatic": 1e-3}
TABLE_TOP = 0.45


@pytest.fixture(scope="module")
def chest(tmp_path_factory):
    root = tmp_path_factory.mktemp("chest")
    urdf = write_partnet_chest(root / "src" / "45135")
    res = import_object(urdf, root / "my_scenes")
    return res, load_scene(res.scene)


@pytest.fixture(scope="module")
def cabinet(tmp_path_factory):
    root = tmp_path_factory.mktemp("cabinet")
    res = import_object(write_mjcf_cabinet(root / "src"), root / "out",
                        ImportConfig(name="mm_cabinet"))
    return res, load_scene(res.scene)


def _object_points(scene, configuration: str) -> np.ndarray:
    model, data = scene.model, scene.make_data(configuration)
    bodies = {b for li in scene.links for b in li.body_ids}
    pts = []
    for g in range(model.ngeom):
        if int(model.geom_bodyid[g]) in bodies and int(model.geom_group[g]) == 2:
            m = int(model.geom_dataid[g])
            v = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] +
                                model.mesh_vertnum[m]]
            pts.append(v @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g])
    return np.concatenate(pts)


def _source_bounds(*groups) -> tuple[np.ndarray, np.ndarray]:
    boxes = [b for g in groups for b in g.values()]
    return (np.min([lo for lo, _ in boxes], axis=0).astype(float),
            np.max([hi for _, hi in boxes], axis=0).astype(float))


def test_partnet_urdf_becomes_a_scene_in_a_folder_of_its_own(chest):
    res, scene = chest
    folder = res.scene.parent
    assert res.scene.name == "partnet_45135.xml"  # a mobility.urdf: named after its folder
    # the scene, its assets and the stage beside them: the folder holds everything it needs
    assert sorted(p.name for p in folder.iterdir()) == ["assets", "partnet_45135.xml", "robots",
                                                        "stage.xml"]
    assert all(p.parent == folder / "assets" and p.name.startswith("partnet_45135_")
               for p in res.assets)
    assert {"stage.xml", "assets/table.png", "robots/puma560/puma560.xml"} <= \
        {p.relative_to(folder).as_posix() for p in res.stage}
    text = res.scene.read_text()
    assert '<include file="stage.xml"/>' in text and str(REPO) not in text.split("-->", 1)[1]
    # links: the fixed joint merged the carcass into the root; a prismatic and a revolute joint
    assert [li.name for li in scene.links] == ["object", "link_0", "link_1"]
    got = {j.name: (j.type, j.parent, j.child) for j in scene.joints}
    assert got == {"joint_0": ("prismatic", "object", "link_0"),
                   "joint_1": ("revolute", "object", "link_1")}
    assert any("fixed joint 'joint_2'" in n for n in res.notes)
    # collisions: one oriented box per panel (the default), where the arm finds grasp points
    model = scene.model
    col = [g for g in range(model.ngeom) if model.geom_group[g] == 3
           and any(int(model.geom_bodyid[g]) in li.body_ids for li in scene.links)]
    assert len(col) == len(CHEST_CARCASS) + len(CHEST_LID) + len(CHEST_DRAWER)
    assert all(model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX for g in col)
    # configurations: closed, then the drawer out 10 cm and the lid up 30 deg
    assert scene.configuration("a") == {"joint_0": 0.0, "joint_1": 0.0}
    assert scene.joint("joint_0").value_b == pytest.approx(0.10)
    assert scene.joint("joint_1").value_b == pytest.approx(math.radians(30), abs=1e-6)
    assert not physics_warnings(scene, 0.5, "b")


def test_partnet_urdf_axes_scale_and_placement_follow_the_source(chest):
    """The URDF's y-up meshes (turned by PartNet's fixed joint) come out z-up: axes, hinge
    point and size as the chest was built, scaled to 25 cm, centred on the table."""
    res, scene = chest
    pts = _object_points(scene, "a")
    lo, hi = _source_bounds(CHEST_CARCASS, CHEST_LID, CHEST_DRAWER)
    s = res.scale
    assert s == pytest.approx(0.25 / np.max(hi - lo))
    np.testing.assert_allclose(pts.max(0) - pts.min(0), s * (hi - lo), atol=1e-6)
    assert pts[:, 2].min() == pytest.approx(TABLE_TOP + 0.0005, abs=1e-6)
    np.testing.assert_allclose((pts.max(0) + pts.min(0))[:2] / 2, 0.0, atol=1e-6)
    lid, drawer = scene.joint("joint_1"), scene.joint("joint_0")
    np.testing.assert_allclose(lid.axis, CHEST_HINGE_AXIS, atol=1e-9)
    np.testing.assert_allclose(drawer.axis, CHEST_SLIDE_AXIS, atol=1e-9)
    np.testing.assert_allclose(lid.point, pts.min(0) + s * (CHEST_HINGE_POINT - lo), atol=1e-6)
    assert drawer.range[1] == pytest.approx(0.5 * s, rel=1e-5)  # written with 6 digits
    # and in B the lid's front went up, the drawer came out along +x by 10 cm
    pb = _object_points(scene, "b")
    assert pb[:, 2].max() > pts[:, 2].max() + 0.05
    assert pb[:, 0].max() == pytest.approx(pts[:, 0].max() + 0.10, abs=1e-6)


def test_mjcf_with_scaled_meshes_and_euler_orientations(cabinet):
    """Millimetre STL meshes scaled by the file, euler orientations in degrees on every body:
    the door's hinge comes out vertical at the cabinet's front edge, opening outwards."""
    res, scene = cabinet
    assert [li.name for li in scene.links] == ["object", "door"]
    (j,) = scene.joints
    assert j.type == "revolute" and j.range[1] == pytest.approx(math.radians(100))
    np.testing.assert_allclose(j.axis, CABINET_HINGE_AXIS, atol=1e-9)
    pts = _object_points(scene, "a")
    lo, hi = _source_bounds(CABINET_MM)
    lo, hi = lo / 1000, hi / 1000
    door_front = max(h[0] for _, h in DOOR_MM.values()) / 1000  # the handle sticks out
    hi[0] = CABINET_HINGE_POINT[0] + door_front
    s = res.scale
    assert s == pytest.approx(0.25 / np.max(hi - lo))
    np.testing.assert_allclose(pts.max(0) - pts.min(0), s * (hi - lo), atol=1e-6)
    np.testing.assert_allclose(j.point, pts.min(0) + s * (CABINET_HINGE_POINT - lo), atol=1e-6)
    assert any("free joint" in n for n in res.notes)
    pb = _object_points(scene, "b")
    assert pb[:, 0].max() > pts[:, 0].max() + 0.02  # the door swung out at the front


@pytest.mark.parametrize("which", ["chest", "cabinet"])
def test_imported_configurations_hold_and_nothing_penetrates(which, request):
    res, scene = request.getfixturevalue(which)
    for c in ("a", "b"):
        data = scene.make_data(c)
        mujoco.mj_step(scene.model, data, nstep=int(round(1.0 / scene.model.opt.timestep)))
        for j in scene.joints:
            assert abs(data.qpos[j.qpos_adr] - j.value(c)) < HOLD_TOL[j.type], (c, j.name)
        data = scene.make_data(c)
        mujoco.mj_collision(scene.model, data)
        bodies = {b for li in scene.links for b in li.body_ids}
        for con in data.contact[:data.ncon]:
            pair = {int(scene.model.geom_bodyid[con.geom1]),
                    int(scene.model.geom_bodyid[con.geom2])}
            assert not (pair & bodies) or con.dist > -1e-3
    # every pair of links excluded from contacts, mass from the collision shapes
    model = scene.model
    sig = [int(model.exclude_signature[e]) for e in range(model.nexclude)]
    excluded = {frozenset((x >> 16, x & 0xFFFF)) for x in sig}
    ids = [li.body_id for li in scene.links]
    assert all(frozenset((a, b)) in excluded for i, a in enumerate(ids) for b in ids[i + 1:])
    assert all(model.body_mass[li.body_id] > 0 for li in scene.links)


@pytest.mark.parametrize("which", ["chest", "cabinet"])
def test_every_imported_part_is_a_uv_mapped_texture_of_its_own(which, request):
    res, scene = request.getfixturevalue(which)
    model = scene.model
    textures = set()
    for li in scene.links:
        geoms = [g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in li.body_ids
                 and int(model.geom_group[g]) <= 2]
        assert geoms, li.name
        for g in geoms:
            assert model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH
            assert model.mesh_texcoordnum[model.geom_dataid[g]] > 0
            tex = int(model.mat_texid[model.geom_matid[g], mujoco.mjtTextureRole.mjTEXROLE_RGB])
            assert tex >= 0
            textures.add(tex)
    assert len(textures) == len(scene.links)  # one texture per part, none shared
    visual_objs = [p for p in res.assets if p.suffix == ".obj" and "hull" not in p.name]
    assert len(visual_objs) == len(scene.links)
    for obj in visual_objs:
        _assert_uv_charts_disjoint(obj)


def _assert_uv_charts_disjoint(obj: Path) -> None:
    """No texel centre inside two triangles (the texture never repeats on the part)."""
    vt, f = [], []
    for line in obj.read_text().splitlines():
        t = line.split()
        if t and t[0] == "vt":
            vt.append([float(x) for x in t[1:3]])
        elif t and t[0] == "f":
            f.append([int(p.split("/")[1]) - 1 for p in t[1:]])
    h, w = cv2.imread(str(obj.with_suffix(".png"))).shape[:2]
    uv = np.c_[np.array(vt)[:, 0] * w, (1 - np.array(vt)[:, 1]) * h]
    cover = np.zeros((h, w), np.int32)
    for tri in np.array(f):
        a, b, c = uv[tri]
        lo = np.floor(uv[tri].min(0)).astype(int)
        hi = np.ceil(uv[tri].max(0)).astype(int)
        assert lo.min() >= 0 and hi[0] <= w and hi[1] <= h, f"{obj.name}: UV outside the atlas"
        xs, ys = np.meshgrid(np.arange(lo[0], hi[0]) + 0.5, np.arange(lo[1], hi[1]) + 0.5)
        p = np.stack([xs, ys], -1)
        d = (b - a)[0] * (c - a)[1] - (b - a)[1] * (c - a)[0]
        if abs(d) < 1e-12:
            continue
        l1 = ((b - p)[..., 0] * (c - p)[..., 1] - (b - p)[..., 1] * (c - p)[..., 0]) / d
        l2 = ((c - p)[..., 0] * (a - p)[..., 1] - (c - p)[..., 1] * (a - p)[..., 0]) / d
        cover[lo[1]:hi[1], lo[0]:hi[0]] += (l1 > 1e-6) & (l2 > 1e-6) & (1 - l1 - l2 > 1e-6)
    assert cover.max() <= 1, f"{obj.name}: {np.sum(cover > 1)} texels in two triangles"


def test_imported_scene_opens_in_plain_mujoco_from_another_folder(chest, monkeypatch):
    res, scene = chest
    monkeypatch.chdir(res.scene.parent.parent)
    rel = Path(res.scene.parent.name) / res.scene.name
    assert mujoco.MjModel.from_xml_path(str(rel)).nbody == scene.model.nbody


def _plain_mujoco_everywhere(path: Path, monkeypatch) -> list[tuple[str, str, mujoco.MjModel]]:
    """``mujoco.MjModel.from_xml_path`` of ``path`` by its absolute path and by a relative one from
    several working directories: its folder, the folder above, a subfolder, a folder of this
    repository with ../robots beside it, and /."""
    folder = path.parent
    out = []
    for cwd in (folder, folder.parent, folder / "assets", REPO / "tests", Path("/")):
        monkeypatch.chdir(cwd)
        for p in (str(path), os.path.relpath(path, cwd)):
            out.append((str(cwd), p, mujoco.MjModel.from_xml_path(p)))
    return out


def test_an_imported_scene_folder_moved_elsewhere_holds_everything_it_needs(chest, tmp_path,
                                                                            monkeypatch):
    """The folder an import writes is self-contained, as a MuJoCo Menagerie model folder: copied
    to another place (another clone, another machine) it opens in MuJoCo's own loader by its
    absolute or a relative path from any working directory and in the harness, where its
    configurations hold; the evaluation's cache key does not depend on where the folder is."""
    res, scene = chest
    moved = tmp_path / "another" / "machine" / "my_scenes"
    shutil.copytree(res.scene.parent, moved)
    path = moved / res.scene.name
    # every file it depends on is in the folder, and the cache key moves with it
    assert all(f.is_relative_to(moved.resolve()) and f.is_file() for f in cache.scene_files(path))
    assert cache.scene_hash(path) == cache.scene_hash(res.scene)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    for cwd, p, model in _plain_mujoco_everywhere(path, monkeypatch):
        assert model.nbody == scene.model.nbody, (cwd, p)
    # the harness's loader, from another working directory: the same object, and it holds still
    monkeypatch.chdir(elsewhere)
    moved_scene = load_scene(os.path.relpath(path, elsewhere))
    assert moved_scene.path == path
    assert [(j.name, j.type, j.value_a, j.value_b) for j in moved_scene.joints] == \
        [(j.name, j.type, j.value_a, j.value_b) for j in scene.joints]
    for c in ("a", "b"):
        assert physics_warnings(moved_scene, 0.2, c) == {}
        data = moved_scene.make_data(c)
        mujoco.mj_step(moved_scene.model, data,
                       nstep=int(round(1.0 / moved_scene.model.opt.timestep)))
        for j in moved_scene.joints:
            assert abs(data.qpos[j.qpos_adr] - j.value(c)) < HOLD_TOL[j.type], (c, j.name)
    # MuJoCo reads the folder's own arm, not this repository's: a body renamed in a copy's arm
    probe = tmp_path / "probe"
    shutil.copytree(moved, probe)
    arm = probe / "robots" / "puma560" / "puma560.xml"
    arm.write_text(arm.read_text().replace('<body name="link1"', '<body name="probe_link1"', 1))
    for cwd, p, model in _plain_mujoco_everywhere(probe / res.scene.name, monkeypatch):
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "puma_probe_link1") >= 0, \
            (cwd, p)


def test_imports_into_one_folder_share_its_stage_and_never_replace_a_foreign_one(tmp_path):
    """A second import into a folder reuses the stage there; the Panda's stage joins the
    PUMA's; a stage copy that differs is replaced on --overwrite only, and a stage.xml that the
    import did not write never."""
    src = write_mjcf_cabinet(tmp_path / "src")
    out = tmp_path / "out"
    first = import_object(src, out, ImportConfig(name="one"))
    stage = out / "stage.xml"
    assert stage in first.stage and "written by sim.author" in stage.read_text()
    second = import_object(src, out, ImportConfig(name="two"))
    assert second.stage == [] and load_scene(second.scene).model.nbody > 0
    panda = import_object(src, out, ImportConfig(name="three", arm="panda"))
    assert {p.relative_to(out).as_posix() for p in panda.stage} >= \
        {"stage_panda.xml", "robots/panda/panda.xml", "robots/panda/assets/LICENSE"}
    assert not any(p.relative_to(out).parts[0] == "assets" for p in panda.stage)  # shared
    assert load_scene(panda.scene).model.nbody > load_scene(first.scene).model.nbody
    # a stage copy of another version: kept unless --overwrite
    stage.write_text(stage.read_text().replace('diffuse="0.5 0.5 0.5"', 'diffuse="0.6 0.6 0.6"'))
    with pytest.raises(AuthorError, match=r"stage\.xml.*--overwrite"):
        import_object(src, out, ImportConfig(name="four"))
    assert not (out / "four.xml").exists() and "0.6 0.6 0.6" in stage.read_text()
    again = import_object(src, out, ImportConfig(name="four", overwrite=True))
    assert again.stage == [stage] and "0.6 0.6 0.6" not in stage.read_text()
    # a stage of the user's own: never replaced
    stage.write_text((BUNDLED_SCENES_DIR / "stage.xml").read_text())
    with pytest.raises(AuthorError, match="not written by sim.author"):
        import_object(src, out, ImportConfig(name="five", overwrite=True))
    assert not (out / "five.xml").exists()


def test_import_is_deterministic(tmp_path):
    src = write_mjcf_cabinet(tmp_path / "src")
    a = import_object(src, tmp_path / "one")
    b = import_object(src, tmp_path / "two")
    assert [p.name for p in a.assets] == [p.name for p in b.assets]
    for p, q in zip(a.assets, b.assets, strict=True):
        assert p.read_bytes() == q.read_bytes(), p.name
    assert a.scene.read_text() == b.scene.read_text()


def test_given_configurations_are_used_and_checked(tmp_path):
    urdf = write_partnet_chest(tmp_path / "src")
    res = import_object(urdf, tmp_path / "out", ImportConfig(
        name="ajar", config_a={"joint_1": math.radians(10)},
        config_b={"joint_1": math.radians(40), "joint_0": 0.0}, collision="hull"))
    scene = load_scene(res.scene)
    hulls = [g for g in range(scene.model.ngeom) if scene.model.geom_group[g] == 3
             and scene.model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
    assert len(hulls) == len(CHEST_CARCASS) + len(CHEST_LID) + len(CHEST_DRAWER)
    assert scene.joint("joint_1").value_a == pytest.approx(math.radians(10))
    assert scene.joint("joint_1").motion == pytest.approx(math.radians(30))
    assert scene.joint("joint_0").static  # asked to stay shut
    assert [j.name for j in scene.moving_joints] == ["joint_1"]


@pytest.mark.parametrize(("case", "kwargs", "needles"), [
    ("unknown joint", dict(config_b={"hinge": 0.1}), ["'hinge'", "joint_0", "joint_1"]),
    ("out of range", dict(config_b={"joint_1": 2.0}), ["joint_1=2", "outside the joint's range"]),
    ("overhang", dict(size=0.9), ["from the table centre", "smaller --size"]),
    ("body on a URDF", dict(body="x"), ["--body", "MJCF"]),
])
def test_bad_import_options_are_refused_and_write_nothing(tmp_path, case, kwargs, needles):
    urdf = write_partnet_chest(tmp_path / "src")
    with pytest.raises(AuthorError) as info:
        import_object(urdf, tmp_path / "out", ImportConfig(**kwargs))
    for needle in needles:
        assert needle in str(info.value), f"{case}: {needle!r} not in {info.value}"
    assert not (tmp_path / "out").exists()


def test_bad_sources_are_refused_with_the_element_and_the_fix(tmp_path):
    urdf = write_partnet_chest(tmp_path / "src")
    text = urdf.read_text()
    cases = {
        "floating": (text.replace('type="prismatic"', 'type="floating"'),
                     ['<joint name="joint_0" type="floating">', "revolute, continuous"]),
        "no limits": (text.replace('<limit lower="0" upper="1.6"/>', ""),
                      ['<joint name="joint_1" type="revolute">', "<limit lower upper>"]),
        "missing mesh": (text.replace("original-3.obj", "nothing.obj"),
                         ['"textured_objs/nothing.obj"', "not found"]),
    }
    for case, (bad, needles) in cases.items():
        path = urdf.with_name(f"{case.replace(' ', '_')}.urdf")
        path.write_text(bad)
        with pytest.raises(AuthorError) as info:
            import_object(path, tmp_path / "out")
        for needle in needles:
            assert needle in str(info.value), f"{case}: {needle!r} not in {info.value}"
    notxml = tmp_path / "model.xml"
    notxml.write_text("<scene/>")
    with pytest.raises(AuthorError, match="neither <robot>"):
        import_object(notxml, tmp_path / "out")
    mjcf = write_mjcf_cabinet(tmp_path / "mj")
    ball = mjcf.with_name("ball.xml")
    ball.write_text(mjcf.read_text().replace('type="hinge"', 'type="ball"'))
    with pytest.raises(AuthorError, match="ball joint"):
        import_object(ball, tmp_path / "out")


def test_an_earlier_import_is_not_overwritten_unless_asked(tmp_path):
    src = write_mjcf_cabinet(tmp_path / "src")
    first = import_object(src, tmp_path / "out")
    before = {p: p.read_bytes() for p in [first.scene, *first.assets]}
    with pytest.raises(AuthorError, match="--overwrite"):
        import_object(src, tmp_path / "out", ImportConfig(density=800))
    assert {p: p.read_bytes() for p in before} == before
    again = import_object(src, tmp_path / "out", ImportConfig(density=800, overwrite=True))
    assert again.scene == first.scene and 'density="800"' in again.scene.read_text()


def test_command_line_imports_and_exits_2_on_bad_input(tmp_path, capsys):
    urdf = write_partnet_chest(tmp_path / "src")
    out = tmp_path / "scenes"
    assert author_main(["import", str(urdf), "--out", str(out), "--name", "chest",
                        "--config-b", "joint_1=25deg", "joint_0=8cm"]) == 0
    text = capsys.readouterr().out
    assert "chest.xml" in text and "texture check" in text and "python -m sim.evaluate" in text
    scene = load_scene(out / "chest.xml")
    assert scene.joint("joint_1").motion == pytest.approx(math.radians(25))
    assert scene.joint("joint_0").motion == pytest.approx(0.08)
    assert author_main(["import", str(urdf), "--out", str(out), "--name", "other",
                        "--config-b", "nope=1"]) == 2
    assert "'nope'" in capsys.readouterr().err
    assert author_main(["import", str(tmp_path / "missing.urdf"), "--out", str(out)]) == 2
    with pytest.raises(SystemExit) as info:
        author_main(["import", str(urdf), "--out", str(out), "--config-b", "lid"])
    assert info.value.code == 2


def test_manipulate_command_moves_the_scenes_own_motion_by_default(tmp_path, monkeypatch):
    """``python -m sim.manipulate SCENE`` without --angle/--distance requests the scene's own
    A -> B motion (here 25 deg, neither of the old fixed defaults)."""
    from sim.manipulate import ManipulationError
    from sim.manipulate import cli as man

    urdf = write_partnet_chest(tmp_path / "src")
    res = import_object(urdf, tmp_path / "out", ImportConfig(
        name="lid25", config_b={"joint_1": math.radians(25), "joint_0": 0.0}))
    asked = {}

    def fake(scene, estimate, amount, **kwargs):
        asked["amount"], asked["joint"] = amount, estimate.name
        raise ManipulationError("stop here")

    monkeypatch.setattr(man, "manipulate", fake)
    monkeypatch.setattr(man, "build_world", lambda scene: None)
    assert man.main([str(res.scene), "--out", str(tmp_path / "m")]) == 2
    assert asked == {"amount": pytest.approx(math.radians(25)), "joint": "joint_1"}
    man.main([str(res.scene), "--out", str(tmp_path / "m"), "--angle", "10"])
    assert asked["amount"] == pytest.approx(math.radians(10))


def _write_textured_urdf(folder: Path, image: np.ndarray) -> Path:
    """A URDF of a box with a hinged flap, each an OBJ with its own UVs and ``image``."""
    import trimesh
    from PIL import Image

    folder.mkdir(parents=True)
    for name, (lo, hi) in {"base": ((-0.1, -0.1, 0.0), (0.1, 0.1, 0.12)),
                           "flap": ((-0.1, -0.1, 0.12), (0.1, 0.1, 0.13))}.items():
        m = trimesh.creation.box(np.subtract(hi, lo))
        m.apply_translation(np.add(lo, hi) / 2)
        m = m.subdivide().subdivide()
        uv = (m.vertices[:, :2] - m.vertices[:, :2].min(0)) / np.ptp(m.vertices[:, :2], 0)
        uv = 0.1 + 0.8 * (0.7 * uv + 0.3 * (m.vertices[:, 2:3] / 0.13))
        m.visual = trimesh.visual.TextureVisuals(uv=np.clip(uv, 0, 1),
                                                 image=Image.fromarray(image))
        (folder / name).mkdir()
        m.export(folder / name / f"{name}.obj")
    (folder / "box.urdf").write_text("""<robot name="box">
  <link name="base"><visual><geometry><mesh filename="base/base.obj"/></geometry></visual></link>
  <link name="flap"><visual><geometry><mesh filename="flap/flap.obj"/></geometry></visual></link>
  <joint name="flap_hinge" type="revolute"><parent link="base"/><child link="flap"/>
    <origin xyz="-0.1 0 0.12"/><axis xyz="0 -1 0"/><limit lower="0" upper="1.5"/></joint>
</robot>""")
    return folder / "box.urdf"


def test_texture_source_keeps_the_meshes_own_textures_and_the_check_judges_them(tmp_path):
    from sim.texture_check import TextureError, check_texture

    rng = np.random.default_rng(1)
    rich = cv2.resize((rng.random((64, 64, 3)) * 255).astype(np.uint8), (512, 512),
                      interpolation=cv2.INTER_NEAREST)
    rich = cv2.GaussianBlur(rich, (0, 0), 1.0)
    res = import_object(_write_textured_urdf(tmp_path / "rich", rich), tmp_path / "out",
                        ImportConfig(name="rich", texture="source"))
    scene = load_scene(res.scene)
    png = next(p for p in res.assets if p.name == "rich_flap.png")
    np.testing.assert_array_equal(cv2.imread(str(png))[..., ::-1], rich)  # the source's image
    assert not check_texture(scene).failing
    plain = np.full((512, 512, 3), 140, np.uint8)
    res = import_object(_write_textured_urdf(tmp_path / "plain", plain), tmp_path / "out",
                        ImportConfig(name="plain", texture="source"))
    with pytest.raises(TextureError, match="part 'object'.*\n.*part 'flap'"):
        check_texture(load_scene(res.scene))
    # a mesh without a texture of its own cannot keep one
    with pytest.raises(AuthorError, match="no texture of its own.*--texture generated"):
        import_object(write_partnet_chest(tmp_path / "chest"), tmp_path / "out",
                      ImportConfig(texture="source"))


def test_assets_unwrap_any_mesh_at_the_asked_texel_without_overlap(tmp_path):
    """sim.assets.texture_mesh on a sphere: every triangle its own atlas region, its texels the
    asked size (3-D area over UV area), the texture deterministic; bad input a clear error."""
    import trimesh

    from sim.assets import texture_mesh, unwrap

    sphere = trimesh.creation.icosphere(3, 0.05)
    part = texture_mesh(sphere.vertices, sphere.faces, tmp_path, "ball", texel=0.0008)
    _assert_uv_charts_disjoint(part.obj)
    mesh = unwrap(sphere.vertices, sphere.faces, 0.0008)
    assert mesh.texel == 0.0008 and (mesh.width, mesh.height) == (part.width, part.height)
    uv = mesh.uv * [mesh.width, mesh.height]
    p = mesh.positions[mesh.faces]
    area3 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    t = uv[mesh.faces]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    area_uv = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert np.median(np.sqrt(area3 / area_uv)) == pytest.approx(0.0008, rel=0.1)
    np.testing.assert_allclose(mesh.positions[mesh.faces], sphere.vertices[sphere.faces])
    again = texture_mesh(sphere.vertices, sphere.faces, tmp_path / "again", "ball",
                         texel=0.0008)
    assert again.obj.read_bytes() == part.obj.read_bytes()
    assert again.png.read_bytes() == part.png.read_bytes()
    # a coarser texel where the atlas would be too large
    big = unwrap(sphere.vertices * 20, sphere.faces, 0.0008, max_size=1024)
    assert big.texel > 0.0008 and max(big.width, big.height) <= 1024
    with pytest.raises(ValueError, match=r"vertices of shape \(n >= 3, 3\)"):
        unwrap(np.zeros((4, 2)), sphere.faces)
    with pytest.raises(ValueError, match="faces index vertices"):
        unwrap(sphere.vertices[:10], sphere.faces)
    with pytest.raises(ValueError, match="degenerate"):
        unwrap(np.zeros((3, 3)), np.array([[0, 1, 2]]))
