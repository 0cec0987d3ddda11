"""A small renderer of a richly textured hinged object for the vision front-end tests.

Until the harness captures scenes with the arm, the SfM/dense/match tests need image sets with a
known answer. This module builds a two-link "laptop" (a base box and a lid plate joined by a
revolute hinge) with seeded random-noise textures, on a textured floor with textured walls, and
renders it with pyrender from two rings of cameras (OpenCV intrinsics fx = fy = 554.26, 640x480).

Ground truth (camera poses, the hinge, surface samples) is returned to the tests only; the image
folders hold ``images/*.png`` and ``cameras.json`` (K and per-image ``T_world_camera``) like a
capture from ``sim.capture``; nothing else.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import sim  # noqa: F401  (selects the EGL platform before any OpenGL import)
from sim.camera import convert_camera_pose, intrinsics_matrix

np.infty = np.inf  # noqa: NPY201  pyrender 0.1.45 still uses np.infty, removed in numpy 2

WIDTH, HEIGHT = 640, 480
FOCAL = 554.26  # pixels; 60 degrees horizontal field of view at 640 px
K = intrinsics_matrix(FOCAL, FOCAL, (WIDTH - 1) / 2.0, (HEIGHT - 1) / 2.0)

# Object geometry in metres, world frame z up, the floor at z = 0.
BASE_SIZE = np.array([0.30, 0.22, 0.06])  # base box, centred on the origin in x, y
LID_SIZE = np.array([0.30, 0.22, 0.015])  # lid plate, hinged on the base's back top edge
HINGE_POINT = np.array([0.0, 0.11, 0.06])  # a point on the hinge axis (back top edge of the base)
HINGE_AXIS = np.array([1.0, 0.0, 0.0])  # hinge direction
#: Lid opening angle in configuration A and B (radians about HINGE_AXIS, 0 = closed).
LID_ANGLE = {"a": np.deg2rad(25.0), "b": np.deg2rad(55.0)}


def noise_texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Multi-scale coloured noise, (size, size, 3) uint8: non-repeating texture SIFT loves."""
    import cv2

    img = np.zeros((size, size, 3))
    for cells, weight in ((4, 0.6), (16, 1.0), (64, 0.8), (size // 4, 0.5)):
        small = rng.random((cells, cells, 3))
        img += weight * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    img -= img.min()
    img /= img.max()
    return (img * 255).astype(np.uint8)


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) about a unit axis through the origin (Rodrigues)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def box_quads(size: np.ndarray, centre: np.ndarray) -> list[np.ndarray]:
    """The six faces of an axis-aligned box as (4, 3) corner arrays, counter-clockwise outward."""
    hx, hy, hz = np.asarray(size) / 2.0
    c = np.asarray(centre, float)
    v = np.array([[x, y, z] for x in (-hx, hx) for y in (-hy, hy) for z in (-hz, hz)]) + c
    # vertex index = 4*ix + 2*iy + iz
    faces = [(0, 2, 6, 4), (1, 5, 7, 3), (0, 4, 5, 1), (2, 3, 7, 6), (0, 1, 3, 2), (4, 6, 7, 5)]
    return [v[list(f)] for f in faces]


@dataclass
class Part:
    """A textured quad: corners (4, 3) in the world, a texture (h, w, 3) uint8, a link index."""

    corners: np.ndarray
    texture: np.ndarray
    link: int  # 0 = static (base, floor, walls), 1 = lid
    is_object: bool = True


@dataclass
class FixtureSet:
    """One rendered configuration: folder, truth camera poses, surface samples per link."""

    folder: Path
    names: list[str]
    T_world_camera: np.ndarray  # (n, 4, 4) OpenCV convention
    object_points: np.ndarray  # (m, 3) samples of the object surface (both links)
    object_links: np.ndarray  # (m,) link of each sample
    extra: dict = field(default_factory=dict)


def build_parts(config: str, seed: int = 0) -> list[Part]:
    """Quads of the scene in configuration ``config`` ('a' or 'b'); textures fixed by ``seed``."""
    rng = np.random.default_rng(seed)
    parts: list[Part] = []
    base = box_quads(BASE_SIZE, [0.0, 0.0, BASE_SIZE[2] / 2])
    for q in base[:5] + base[5:]:
        parts.append(Part(q, noise_texture(rng, 256), 0))
    lid_closed = box_quads(LID_SIZE, [0.0, 0.0, BASE_SIZE[2] + LID_SIZE[2] / 2])
    R = rotation_about(HINGE_AXIS, -LID_ANGLE[config])  # opening lifts the front edge (-y)
    for q in lid_closed:
        moved = (q - HINGE_POINT) @ R.T + HINGE_POINT
        parts.append(Part(moved, noise_texture(rng, 256), 1))
    # Floor (a table top) and four walls: static background, textured.
    f = 0.9
    floor = np.array([[-f, -f, 0.0], [f, -f, 0.0], [f, f, 0.0], [-f, f, 0.0]])
    parts.append(Part(floor, noise_texture(rng, 1024), 0, is_object=False))
    for i in range(4):
        a0, a1 = i * np.pi / 2, (i + 1) * np.pi / 2
        p0 = np.array([np.cos(a0) + np.cos(a1), np.sin(a0) + np.sin(a1), 0.0]) * f
        p1 = np.array([np.cos(a1) + np.cos(a1 + np.pi / 2), np.sin(a1) + np.sin(a1 + np.pi / 2),
                       0.0]) * f
        wall = np.array([p0, p1, p1 + [0, 0, 1.0], p0 + [0, 0, 1.0]])
        parts.append(Part(wall[::-1], noise_texture(rng, 512), 0, is_object=False))
    return parts


def ring_poses(n_views: int, radius: float = 0.5, heights=(0.28, 0.50)) -> np.ndarray:
    """OpenCV ``T_world_camera`` (n, 4, 4) on rings around the origin, looking at the object."""
    per_ring = n_views // len(heights)
    poses = []
    for r_i, h in enumerate(heights):
        for k in range(per_ring):
            ang = 2 * np.pi * k / per_ring + r_i * np.pi / per_ring
            c = np.array([radius * np.cos(ang), radius * np.sin(ang), h])
            target = np.array([0.0, 0.0, 0.08])
            z = target - c
            z /= np.linalg.norm(z)
            x = np.cross(z, [0, 0, 1.0])
            x /= np.linalg.norm(x)
            y = np.cross(z, x)
            T = np.eye(4)
            T[:3, :3] = np.column_stack([x, y, z])
            T[:3, 3] = c
            poses.append(T)
    return np.array(poses)


def _pyrender_scene(parts: list[Part]):
    import pyrender

    scene = pyrender.Scene(bg_color=[0.5, 0.5, 0.5, 1.0], ambient_light=[1.0, 1.0, 1.0])
    for p in parts:
        c = p.corners
        positions = np.array([c[0], c[1], c[2], c[0], c[2], c[3]], dtype=np.float32)
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 0], [1, 1], [0, 1]], dtype=np.float32)
        tex = pyrender.Texture(source=p.texture, source_channels="RGB")
        mat = pyrender.MetallicRoughnessMaterial(baseColorTexture=tex, doubleSided=True)
        prim = pyrender.Primitive(positions=positions, texcoord_0=uv, material=mat, mode=4)
        scene.add(pyrender.Mesh([prim]))
    return scene


_RENDERER = None


def _renderer():
    global _RENDERER
    if _RENDERER is None:
        import pyrender

        _RENDERER = pyrender.OffscreenRenderer(WIDTH, HEIGHT)
    return _RENDERER


def sample_object(parts: list[Part], spacing: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """Points (m, 3) on the object's quads every ``spacing`` metres, and their link (m,)."""
    pts, links = [], []
    for p in parts:
        if not p.is_object:
            continue
        c = p.corners
        u, v = c[1] - c[0], c[3] - c[0]
        nu = max(2, int(np.linalg.norm(u) / spacing))
        nv = max(2, int(np.linalg.norm(v) / spacing))
        s, t = np.meshgrid(np.linspace(0, 1, nu), np.linspace(0, 1, nv))
        q = c[0] + s.reshape(-1, 1) * u + t.reshape(-1, 1) * v
        pts.append(q)
        links.append(np.full(len(q), p.link))
    return np.concatenate(pts), np.concatenate(links)


def render_set(folder: Path, config: str, n_views: int = 36, seed: int = 0,
               write_poses: bool = True, render: bool = True) -> FixtureSet:
    """Render configuration ``config`` into ``folder/images`` and write ``folder/cameras.json``;
    with ``render=False`` only the truth of a set rendered there before (same arguments)."""
    import cv2
    import pyrender

    folder = Path(folder)
    parts = build_parts(config, seed)
    poses = ring_poses(n_views)
    names = [f"view_{i:03d}.png" for i in range(len(poses))]
    if not render:
        return FixtureSet(folder, names, poses, *sample_object(parts))
    (folder / "images").mkdir(parents=True, exist_ok=True)
    scene = _pyrender_scene(parts)
    cam = pyrender.IntrinsicsCamera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2] + 0.5, cy=K[1, 2] + 0.5,
                                    znear=0.02, zfar=5.0)
    node = scene.add(cam, pose=np.eye(4))
    for name, T in zip(names, poses, strict=True):
        scene.set_pose(node, convert_camera_pose(T))
        color, _ = _renderer().render(scene, flags=pyrender.RenderFlags.FLAT)
        cv2.imwrite(str(folder / "images" / name), color[:, :, ::-1])
    if write_poses:
        data = {"K": K.tolist(), "width": WIDTH, "height": HEIGHT,
                "images": [{"name": n, "T_world_camera": T.tolist()} for n, T in
                           zip(names, poses, strict=True)]}
        (folder / "cameras.json").write_text(json.dumps(data, indent=2))
    pts, links = sample_object(parts)
    return FixtureSet(folder, names, poses, pts, links)


def render_view(path: Path, config: str, T_world_camera: np.ndarray, seed: int = 0) -> Path:
    """Render one image of configuration ``config`` from ``T_world_camera`` (OpenCV) into
    ``path`` (a fresh view, e.g. for registration by PnP)."""
    import cv2
    import pyrender

    scene = _pyrender_scene(build_parts(config, seed))
    cam = pyrender.IntrinsicsCamera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2] + 0.5, cy=K[1, 2] + 0.5,
                                    znear=0.02, zfar=5.0)
    scene.add(cam, pose=convert_camera_pose(np.asarray(T_world_camera, float)))
    color, _ = _renderer().render(scene, flags=pyrender.RenderFlags.FLAT)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), color[:, :, ::-1])
    return path


def look_at(eye, target=(0.0, 0.0, 0.08)) -> np.ndarray:
    """OpenCV ``T_world_camera`` at ``eye`` looking at ``target``, image x horizontal."""
    c, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - c
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = c
    return T


def true_hinge() -> dict:
    """The hinge moving configuration A to B: axis direction, a point, the angle B - A."""
    angle = -(LID_ANGLE["b"] - LID_ANGLE["a"])
    return {"type": "revolute", "axis_direction": HINGE_AXIS.copy(), "axis_point": HINGE_POINT,
            "angle": angle}


def lid_transform_a_to_b() -> np.ndarray:
    """(4, 4) rigid motion of the lid from configuration A to B, world frame."""
    R = rotation_about(HINGE_AXIS, true_hinge()["angle"])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = HINGE_POINT - R @ HINGE_POINT
    return T


# --- shared pytest fixtures (imported by the test modules) -------------------------------------

#: Views per rendered test set: two rings of 18 (20 degrees apart). Fewer views keep the SfM tests
#: fast; benchmarks/bench_sfm.py also measures 72.
TEST_VIEWS = 36


def camera_centres(model_dir) -> dict:
    """Camera centre (3,) per image name of a COLMAP model folder."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model_dir))
    out = {}
    for img in rec.images.values():
        if img.has_pose:
            out[img.name] = np.asarray(img.projection_center())
    return out


def align_to_truth(model_dir, truth: FixtureSet):
    """Similarity (Umeyama on camera centres) from a model's frame to the world, and the
    per-camera centre errors (m,) in metres after it."""
    from artrecon.procrustes import similarity_transform

    centres = camera_centres(model_dir)
    names = sorted(centres)
    idx = [truth.names.index(n) for n in names]
    src = np.array([centres[n] for n in names])
    dst = truth.T_world_camera[idx, :3, 3]
    S = similarity_transform(src, dst)
    return S, np.linalg.norm(S.apply(src) - dst, axis=1)


def axis_errors(direction, point, true_direction, true_point) -> tuple[float, float]:
    """Axis angle error (deg, sign-free) and distance (m) between two 3D lines."""
    d1 = np.asarray(direction) / np.linalg.norm(direction)
    d2 = np.asarray(true_direction) / np.linalg.norm(true_direction)
    ang = float(np.degrees(np.arccos(np.clip(abs(d1 @ d2), 0, 1))))
    n = np.cross(d1, d2)
    w = np.asarray(point) - np.asarray(true_point)
    if np.linalg.norm(n) < 1e-6:
        dist = float(np.linalg.norm(w - (w @ d2) * d2))
    else:
        dist = float(abs(w @ n) / np.linalg.norm(n))
    return ang, dist
