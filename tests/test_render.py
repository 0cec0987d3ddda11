"""sim.render: geometry of the rendered images against analytic ray casting.

Small MJCF models written here (boxes, a sphere, a hinge, a textured OBJ mesh, a textured plane)
are rendered and compared with what the pinhole model ``K``, ``T_world_camera`` predicts.
"""

import gc

import mujoco
import numpy as np
import pytest
from PIL import Image

from sim import render as R
from sim.camera import intrinsics_matrix
from sim.render.context import _Renderer

#: Rendered depth must put surfaces within this distance (m) of the true ones (issue 3).
DEPTH_TOL = 1e-3
#: Labels may disagree with the analytic ray cast only on silhouette pixels; the share of such
#: pixels in a 160 x 120 view of a few objects is about 1 %, so 3 % catches real errors.
LABEL_MISMATCH_MAX = 0.03

W, H = 160, 120
# deliberately off-centre principal point and non-square pixels, to catch convention slips
K = intrinsics_matrix(150.0, 140.0, 83.3, 57.1)

SCENE = """<mujoco>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1" directional="true"/>
    <geom name="floor" type="plane" size="1 1 0.1" rgba="0.4 0.4 0.4 1"/>
    <geom name="box" type="box" size="0.08 0.05 0.1" pos="0.05 -0.12 0.1" euler="0 0 25"
          rgba="1 0 0 1"/>
    <geom name="ball" type="sphere" size="0.07" pos="-0.12 0.1 0.07" rgba="0 1 0 1"/>
    <geom name="hidden_collision" type="box" size="0.3 0.3 0.3" pos="0 0 0.3" group="3"/>
    <geom name="hidden_alpha" type="sphere" size="0.3" pos="0 0 0.3" rgba="1 1 1 0"/>
    <body name="lid" pos="0.15 0.15 0.02">
      <joint name="hinge" type="hinge" axis="0 0 1"/>
      <geom name="flap" type="box" size="0.06 0.02 0.02" pos="0.06 0 0" rgba="0 0 1 1"/>
    </body>
  </worldbody>
</mujoco>"""


def look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """OpenCV ``T_world_camera`` at ``eye`` looking at ``target``."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.c_[x, np.cross(z, x), z]
    T[:3, 3] = eye
    return T


def views(n, seed, radius=(0.6, 0.9), target=(0.0, 0.0, 0.08)):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        az, el = rng.uniform(0, 2 * np.pi), np.deg2rad(rng.uniform(20, 70))
        r = rng.uniform(*radius)
        eye = np.asarray(target) + r * np.array([np.cos(el) * np.cos(az),
                                                 np.cos(el) * np.sin(az), np.sin(el)])
        yield look_at(eye, target)


def pixel_rays(K, T, w, h):
    """Ray origin (3,) and world directions (h*w, 3) scaled so that t is the depth."""
    v, u = np.mgrid[0:h, 0:w]
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)],
                     axis=-1).reshape(-1, 3)
    return T[:3, 3], d_cam @ T[:3, :3].T


def ray_box(o, d, centre, R_wb, half):
    """Entry distance of rays into an oriented box (inf when missed)."""
    o_b = (o - centre) @ R_wb
    d_b = d @ R_wb
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - o_b) / d_b
        t2 = (half - o_b) / d_b
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((tmax >= tmin) & (tmin > 0), tmin, np.inf)


def ray_sphere(o, d, centre, r):
    oc = o - centre
    a = np.sum(d * d, axis=1)
    b = 2 * d @ oc
    c = oc @ oc - r * r
    disc = b * b - 4 * a * c
    t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
    return np.where((disc >= 0) & (t > 0), t, np.inf)


def ray_plane(o, d, half):
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[:, 2]
    p = o + t[:, None] * d
    inside = (np.abs(p[:, 0]) <= half) & (np.abs(p[:, 1]) <= half) & (t > 0)
    return np.where(inside, t, np.inf)


def gid(model, name):
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)


def analytic_cast(model, data, T):
    """Expected (label, depth) of every pixel from exact ray casts against the MJCF geometry."""
    o, d = pixel_rays(K, T, W, H)
    ts, labels = [], []
    for name in ("box", "flap"):
        g = gid(model, name)
        ts.append(ray_box(o, d, data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3),
                          model.geom_size[g]))
        labels.append(g)
    g = gid(model, "ball")
    ts.append(ray_sphere(o, d, data.geom_xpos[g], model.geom_size[g, 0]))
    labels.append(g)
    ts.append(ray_plane(o, d, 1.0))
    labels.append(gid(model, "floor"))
    ts = np.stack(ts)
    best = np.argmin(ts, axis=0)
    depth = ts[best, np.arange(ts.shape[1])]
    lab = np.where(np.isfinite(depth), np.asarray(labels)[best], R.LABEL_BACKGROUND)
    return lab.reshape(H, W), np.where(np.isfinite(depth), depth, 0.0).reshape(H, W)


@pytest.fixture(scope="module")
def scene():
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    data.qpos[0] = 0.7  # the hinge: the flap must be drawn where the joint put it
    mujoco.mj_forward(model, data)
    renderer = R.MjRenderer(model, geom_labels=np.arange(model.ngeom))
    return model, data, renderer


def test_depth_and_labels_match_analytic_geometry(scene):
    model, data, renderer = scene
    for T in views(4, seed=3):
        out = renderer.render(data, K, T, W, H, depth=True, labels=True)
        assert out.color.shape == (H, W, 3) and out.color.dtype == np.uint8
        exp_lab, exp_depth = analytic_cast(model, data, T)
        agree = out.labels == exp_lab
        assert 1 - agree.mean() < LABEL_MISMATCH_MAX
        # hidden geoms (collision group 3, alpha 0) never show up
        assert not np.isin(out.labels, [gid(model, "hidden_collision"),
                                        gid(model, "hidden_alpha")]).any()
        both = agree & (exp_lab != R.LABEL_BACKGROUND)
        err = np.abs(out.depth[both] - exp_depth[both])
        assert both.sum() > 0.3 * W * H
        assert np.max(err) < DEPTH_TOL, f"max depth error {np.max(err) * 1e3:.3f} mm"
        assert np.all(out.depth[out.labels == R.LABEL_BACKGROUND] == 0)


def test_backprojected_depth_lies_on_the_surfaces(scene):
    model, data, renderer = scene
    g_ball, g_box = gid(model, "ball"), gid(model, "box")
    for T in views(3, seed=5, radius=(0.4, 0.6)):
        out = renderer.render(data, K, T, W, H, depth=True, labels=True)
        ball = R.backproject(out.depth, K, T, out.labels == g_ball)
        assert len(ball) > 50
        dist = np.abs(np.linalg.norm(ball - data.geom_xpos[g_ball], axis=1)
                      - model.geom_size[g_ball, 0])
        assert dist.max() < DEPTH_TOL
        box = R.backproject(out.depth, K, T, out.labels == g_box)
        p_b = (box - data.geom_xpos[g_box]) @ data.geom_xmat[g_box].reshape(3, 3)
        q = np.abs(p_b) - model.geom_size[g_box]
        # on the surface of a box: inside every slab, on the boundary of at least one
        assert np.all(q.max(axis=1) < DEPTH_TOL) and np.all(q.max(axis=1) > -DEPTH_TOL)


def test_small_marker_projects_to_K_times_point():
    """A small sphere's pixel centroid is K @ p: the principal-point half-pixel is right."""
    rng = np.random.default_rng(7)
    pts = np.c_[rng.uniform(-0.25, 0.25, (6, 2)), rng.uniform(-0.15, 0.15, 6)]
    geoms = "".join(f'<geom type="sphere" size="0.012" pos="{p[0]} {p[1]} {p[2]}"/>'
                    for p in pts)
    model = mujoco.MjModel.from_xml_string(f"<mujoco><worldbody>{geoms}</worldbody></mujoco>")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    renderer = R.MjRenderer(model, geom_labels=np.arange(model.ngeom))
    w, h = 640, 480
    K2 = intrinsics_matrix(600.0, 580.0, 342.3, 225.8)
    T = look_at([0.9, -0.4, 0.5], [0, 0, 0])
    out = renderer.render(data, K2, T, w, h, labels=True)
    p_cam = (pts - T[:3, 3]) @ T[:3, :3]
    proj = (p_cam @ K2.T)[:, :2] / p_cam[:, 2:]
    for i in range(len(pts)):
        v, u = np.nonzero(out.labels == i)
        assert len(u) > 50
        # a 12 mm sphere at ~1 m covers ~130 pixels; the centroid of its silhouette (an
        # ellipse) lies within (r/d)**2 * |u - cx| < 0.05 px of K p, pixel sampling adds less
        np.testing.assert_allclose([u.mean(), v.mean()], proj[i], atol=0.2)


def _write_textured_quad(tmp_path, width: int = 64, height: int = 64):
    """A 0.2 m square OBJ facing +z with a texture of four coloured quadrants."""
    img = np.zeros((height, width, 3), np.uint8)
    h2, w2 = height // 2, width // 2
    img[:h2, :w2] = [255, 0, 0]      # image top-left: red
    img[:h2, w2:] = [0, 255, 0]      # top-right: green
    img[h2:, :w2] = [0, 0, 255]      # bottom-left: blue
    img[h2:, w2:] = [255, 255, 0]    # bottom-right: yellow
    Image.fromarray(img).save(tmp_path / "quad.png")
    # OBJ convention: vt (0, 0) is the image's bottom-left corner. A fifth vertex behind the
    # quad gives the mesh volume (MuJoCo builds a convex hull).
    (tmp_path / "quad.obj").write_text(
        "v -0.1 -0.1 0\nv 0.1 -0.1 0\nv 0.1 0.1 0\nv -0.1 0.1 0\nv 0 0 -0.05\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n"
        "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\nf 2/2 1/1 5/5\nf 3/3 2/2 5/5\nf 4/4 3/3 5/5\n"
        "f 1/1 4/4 5/5\n")
    return f"""<mujoco><compiler meshdir="{tmp_path}" texturedir="{tmp_path}"/>
      <visual><headlight ambient="1 1 1" diffuse="0 0 0"/></visual>
      <asset><texture name="t" type="2d" file="quad.png"/>
        <material name="m" texture="t" rgba="1 1 1 1"/>
        <mesh name="quad" file="quad.obj"/></asset>
      <worldbody><body pos="0.2 0.1 0.3" euler="0 0 40">
        <joint type="hinge" axis="1 0 0"/>
        <geom type="mesh" mesh="quad" material="m"/></body></worldbody></mujoco>"""


@pytest.mark.parametrize("width, height", [(64, 64), (322, 412)])
def test_textured_mesh_uses_obj_uv_convention_and_geom_pose(tmp_path, width, height):
    """322 x 3 bytes per row is no multiple of 4: uploaded as RGB, OpenGL read the packed rows as
    padded ones, so the texture was sheared and its last rows came from beyond the buffer (the
    imported chest's captures differed from run to run). Two renderers now draw the same."""
    model = mujoco.MjModel.from_xml_string(_write_textured_quad(tmp_path, width, height))
    data = mujoco.MjData(model)
    data.qpos[0] = 0.3
    mujoco.mj_forward(model, data)
    renderer = R.MjRenderer(model)
    # the body frame (not the geom frame: MuJoCo re-centred the mesh) is where the OBJ lives
    T_wb = np.eye(4)
    T_wb[:3, :3] = data.xmat[1].reshape(3, 3)
    T_wb[:3, 3] = data.xpos[1]
    centre = T_wb[:3, 3]
    normal = T_wb[:3, 2]
    T = look_at(centre + 0.5 * normal, centre, up=T_wb[:3, 1])
    w, h = 200, 200
    K2 = intrinsics_matrix(400.0, 400.0, 99.5, 99.5)
    out = renderer.render(data, K2, T, w, h, depth=True)
    expected = {(-0.05, 0.05): [255, 0, 0], (0.05, 0.05): [0, 255, 0],
                (-0.05, -0.05): [0, 0, 255], (0.05, -0.05): [255, 255, 0]}
    for (x, y), rgb in expected.items():
        p = T_wb @ np.array([x, y, 0.0, 1.0])
        pc = np.linalg.inv(T) @ p
        u, v = (K2 @ pc[:3])[:2] / pc[2]
        got = out.color[int(round(v)), int(round(u))].astype(int)
        assert np.abs(got - rgb).max() < 40, f"quadrant {(x, y)}: got {got}, expected {rgb}"
        np.testing.assert_allclose(out.depth[int(round(v)), int(round(u))], pc[2], atol=DEPTH_TOL)
    again = R.MjRenderer(model).render(data, K2, T, w, h).color
    np.testing.assert_array_equal(again, out.color)


def test_plane_texture_repeats_per_unit_length():
    xml = """<mujoco><visual><headlight ambient="1 1 1" diffuse="0 0 0"/></visual>
      <asset><texture name="c" type="2d" builtin="checker" width="64" height="64"
               rgb1="1 1 1" rgb2="0 0 0"/>
        <material name="m" texture="c" texrepeat="4 4" texuniform="true"/></asset>
      <worldbody><geom type="plane" size="1 1 0.1" material="m"/></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    renderer = R.MjRenderer(model)
    T = look_at([0.0, 0.0, 1.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
    w, h = 200, 200
    K2 = intrinsics_matrix(200.0, 200.0, 99.5, 99.5)
    out = renderer.render(data, K2, T, w, h)
    # 4 texture tiles per metre, MuJoCo's checker has 2 x 2 squares per tile: 0.125 m squares
    grey = []
    for i in range(-3, 3):
        for j in range(-3, 3):
            p = np.array([(i + 0.5) * 0.125, (j + 0.5) * 0.125, 0.0, 1.0])
            pc = np.linalg.inv(T) @ p
            u, v = (K2 @ pc[:3])[:2] / pc[2]
            grey.append(out.color[int(round(v)), int(round(u))].mean())
    grey = np.array(grey).reshape(6, 6)
    bright = grey > 127
    assert np.all(np.abs(grey - np.where(bright, 255, 0)) < 60)
    parity = (np.add.outer(np.arange(6), np.arange(6)) % 2).astype(bool)
    assert np.array_equal(bright, parity) or np.array_equal(bright, ~parity)


def test_one_offscreen_renderer_survives_collected_scenes(scene):
    model, data, renderer = scene
    T = next(views(1, seed=11))
    before = renderer.render(data, K, T, W, H, depth=True).depth
    other = R.MjRenderer(mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><geom type='sphere' size='0.1'/></worldbody></mujoco>"))
    other.render(None, K, T, W * 2, H * 2)
    del other
    gc.collect()
    after = renderer.render(data, K, T, W, H, depth=True).depth
    np.testing.assert_array_equal(before, after)
    assert R.offscreen_renderer(W, H) is R.offscreen_renderer(W * 2, H)


def test_bad_arguments_are_clear_errors(scene):
    model, data, renderer = scene
    T = np.eye(4)
    with pytest.raises(ValueError, match=r"\(3, 3\)"):
        renderer.render(data, np.eye(4), T, W, H)
    with pytest.raises(ValueError, match="skew"):
        renderer.render(data, np.array([[100.0, 1, 50], [0, 100, 50], [0, 0, 1]]), T, W, H)
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        renderer.render(data, K, np.eye(3), W, H)
    with pytest.raises(ValueError, match="geom_labels"):
        R.MjRenderer(model, geom_labels=np.zeros(2))
    hfield = """<mujoco><asset><hfield name="h" nrow="3" ncol="3" size="1 1 0.1 0.1"/></asset>
      <worldbody><geom type="hfield" hfield="h"/></worldbody></mujoco>"""
    with pytest.raises(NotImplementedError, match="HFIELD"):
        R.MjRenderer(mujoco.MjModel.from_xml_string(hfield))


def test_culling_and_constant_light_loops_leave_every_pixel_as_pyrender_draws_it(
        scene, monkeypatch):
    """The colour pass's speed-ups (sim.render: nodes outside the frustum hidden, light loops
    with compile-time bounds, the colour pass read back without its depth) change no pixel of
    the colour, depth or label images."""
    model, data, renderer = scene
    # close views (some geoms out of the frame, some behind the camera) and far ones
    poses = list(views(3, seed=21, radius=(0.25, 0.35), target=(0.1, -0.1, 0.05)))
    poses += list(views(2, seed=22))
    fast = [renderer.render(data, K, T, W, H, depth=True, labels=True) for T in poses]
    hidden = []
    for T in poses[:3]:
        renderer.render(data, K, T, W, H)
        hidden.append(sum(not n.mesh.is_visible for n in renderer.geom_nodes.values()))
    assert max(hidden) > 0, "no view culled anything: the test does not test culling"
    monkeypatch.setattr(R.MjRenderer, "cull_offscreen", False)
    monkeypatch.setattr(_Renderer, "constant_light_loops", False)
    for T, f in zip(poses, fast, strict=True):
        plain = renderer.render(data, K, T, W, H, depth=True, labels=True)
        np.testing.assert_array_equal(f.color, plain.color)
        np.testing.assert_array_equal(f.depth, plain.depth)
        np.testing.assert_array_equal(f.labels, plain.labels)


def test_a_ctrl_c_inside_an_opengl_calls_arguments_is_an_interrupt(monkeypatch):
    """PyOpenGL converts a call's arguments in Python; a SIGINT landing there surfaced as
    ctypes.ArgumentError (seen in CI: an interrupted capture ended in a traceback). The renderer
    turns it back into KeyboardInterrupt; any other ArgumentError stays what it is."""
    import ctypes

    import pyrender

    from sim.render import context

    renderer = object.__new__(context._Renderer)
    renderer._program_cache = None
    for message, expected in (("argument 3: KeyboardInterrupt: ", KeyboardInterrupt),
                              ("argument 1: TypeError: wrong type", ctypes.ArgumentError)):
        def fail(self, scene, flags, seg_node_map=None, message=message):
            raise ctypes.ArgumentError(message)

        monkeypatch.setattr(pyrender.renderer.Renderer, "render", fail)
        with pytest.raises(expected):
            renderer.render(None, 0)
