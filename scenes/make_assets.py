"""Generate the textures and textured meshes of the stage and the bundled scenes.

Run from anywhere::

    python scenes/make_assets.py            # writes scenes/assets/
    python scenes/make_assets.py --out DIR  # writes elsewhere (the tests check determinism so)

Everything is deterministic: one master seed, one derived seed per part (from the part's name),
numpy's PCG64 generator, OpenCV drawing. Each part is one OBJ mesh with UVs and one PNG texture.
Every face of every mesh has its own region of its texture atlas, so no piece of texture appears
twice anywhere in the world (a repeated pattern can make SfM fold a ring of cameras). The
texture is multi-scale colour noise under many random coloured blobs and strokes, which gives
corners at all scales from about 2 to 60 texels.

Geometry is in metres in the frame of the MJCF body that carries the mesh (the geoms that use
the meshes have no pos or quat). The z = 0 plane of an object's root body is the table top.

Texel size: the capture camera (fx = 554 px) at about 0.4 m sees about 0.7 mm per pixel at the
image centre and 1.4 mm per pixel for a 20 cm object filling half the image, so object parts get
0.5 - 1.2 mm per texel, the table about 1 mm and the far background (floor, walls, 1 - 2 m away)
4 - 7 mm. The achieved texel size of every part is printed.
"""

from __future__ import annotations

import argparse
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

#: Master seed of every asset; change it to get a different (but again deterministic) world.
SEED = 2024
#: Blank border, in texels, around each face's region in an atlas (keeps mipmaps from mixing
#: neighbouring faces at the distances the camera sees them).
PAD = 3
#: Segments of a full circle for cylinders and disks (visual only; collisions use primitives).
SEGMENTS = 48

HERE = Path(__file__).resolve().parent


# --------------------------------------------------------------------------------------------
# Geometry: patches (planar-parameterised pieces of surface) and their atlas layout
# --------------------------------------------------------------------------------------------


@dataclass
class Patch:
    """A piece of surface whose texture coordinates are metres in its own plane.

    positions : (n, 3) float, vertices in the body frame.
    normals : (n, 3) float, unit vertex normals.
    local : (n, 2) float, texture-plane coordinates in metres, in [0, size[0]] x [0, size[1]].
    triangles : (m, 3) int, counter-clockwise seen from outside.
    size : (2,) float, extent of ``local`` in metres.
    coarse : float, multiplier of the part's texel size for this patch.
    """

    positions: np.ndarray
    normals: np.ndarray
    local: np.ndarray
    triangles: np.ndarray
    size: np.ndarray
    coarse: float = 1.0
    """Multiplier of the part's texel size for this patch (surfaces only seen from afar)."""


def rot_z(yaw: float) -> np.ndarray:
    """Rotation matrix (3, 3) about +z by ``yaw`` radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quad(corners: np.ndarray, coarse: float = 1.0) -> Patch:
    """A planar quad from four corners (4, 3), counter-clockwise seen from outside."""
    corners = np.asarray(corners, dtype=float)
    e1 = corners[1] - corners[0]
    e2 = corners[3] - corners[0]
    w, h = np.linalg.norm(e1), np.linalg.norm(e2)
    n = np.cross(e1, e2)
    n /= np.linalg.norm(n)
    local = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    return Patch(corners, np.tile(n, (4, 1)), local, np.array([[0, 1, 2], [0, 2, 3]]),
                 np.array([w, h]), coarse)


def box(lo, hi, R: np.ndarray | None = None, about=(0.0, 0.0, 0.0), skip=()) -> list[Patch]:
    """Six quads of the box [lo, hi], rotated by ``R`` about the point ``about``.

    ``skip`` names faces to leave out ("-x", "+x", "-y", "+y", "-z", "+z"), for faces that
    can never be seen (e.g. resting on the table).
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    R = np.eye(3) if R is None else R
    about = np.asarray(about, float)
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    faces = {
        "-x": [[x0, y1, z0], [x0, y0, z0], [x0, y0, z1], [x0, y1, z1]],
        "+x": [[x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1]],
        "-y": [[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]],
        "+y": [[x1, y1, z0], [x0, y1, z0], [x0, y1, z1], [x1, y1, z1]],
        "-z": [[x0, y1, z0], [x1, y1, z0], [x1, y0, z0], [x0, y0, z0]],
        "+z": [[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]],
    }
    out = []
    for name, c in faces.items():
        if name in skip:
            continue
        out.append(quad((np.asarray(c) - about) @ R.T + about))
    return out


def bar(p0, p1, width: float, z0: float, z1: float) -> list[Patch]:
    """A flat bar (box) in the xy plane from point ``p0`` to ``p1`` (2,), between heights z."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    yaw = float(np.arctan2(d[1], d[0]))
    c = (p0 + p1) / 2
    lo = [c[0] - length / 2, c[1] - width / 2, z0]
    hi = [c[0] + length / 2, c[1] + width / 2, z1]
    return box(lo, hi, rot_z(yaw), about=(c[0], c[1], 0.0))


def cylinder(center, radius: float, half_height: float, axis: str = "z",
             caps=(True, True), pieces: int = 1, coarse=(1.0, 1.0, 1.0)) -> list[Patch]:
    """Side and caps of a cylinder about a coordinate axis.

    The side is unrolled into ``pieces`` patches (so a long side fits an atlas); ``coarse``
    multiplies the texel size of (side, bottom cap, top cap) for surfaces seen only from afar.
    """
    center = np.asarray(center, float)
    # Built about z, then coordinates are cyclically permuted for x or y axes (a rotation).
    perm = {"z": [0, 1, 2], "x": [1, 2, 0], "y": [2, 0, 1]}[axis]

    def place(v, shift=True):
        out = np.empty_like(v)
        out[..., perm] = v
        return out + center if shift else out

    patches = []
    per = SEGMENTS // pieces
    for k in range(pieces):
        t = np.linspace(2 * np.pi * k / pieces, 2 * np.pi * (k + 1) / pieces, per + 1)
        ring = np.stack([np.cos(t), np.sin(t)], axis=-1)
        n = len(t)
        pos = np.concatenate([np.c_[radius * ring, np.full(n, -half_height)],
                              np.c_[radius * ring, np.full(n, half_height)]])
        nrm = np.concatenate([np.c_[ring, np.zeros(n)]] * 2)
        arc = radius * (t - t[0])
        local = np.concatenate([np.c_[arc, np.zeros(n)],
                                np.c_[arc, np.full(n, 2 * half_height)]])
        tris = []
        for i in range(per):
            a, b, c, d = i, i + 1, n + i + 1, n + i
            tris += [[a, b, c], [a, c, d]]
        patches.append(Patch(place(pos), place(nrm, False), local, np.array(tris),
                             np.array([arc[-1], 2 * half_height]), coarse[0]))
    t = np.linspace(0.0, 2 * np.pi, SEGMENTS, endpoint=False)
    rim = radius * np.stack([np.cos(t), np.sin(t)], axis=-1)
    k = SEGMENTS
    for sign, want, scale in zip((-1.0, 1.0), caps, coarse[1:], strict=True):
        if not want:
            continue
        p = np.concatenate([[[0.0, 0.0, sign * half_height]],
                            np.c_[rim, np.full(k, sign * half_height)]])
        nr = np.tile([0.0, 0.0, sign], (k + 1, 1))
        loc = np.concatenate([[[radius, radius]], rim + radius])
        if sign < 0:  # seen from below: mirror the texture plane so it is not mirrored on screen
            loc[:, 0] = 2 * radius - loc[:, 0]
        tri = [[0, 1 + i, 1 + (i + 1) % k] if sign > 0 else [0, 1 + (i + 1) % k, 1 + i]
               for i in range(k)]
        patches.append(Patch(place(p), place(nr, False), loc, np.array(tri),
                             np.array([2 * radius, 2 * radius]), scale))
    return patches


def pack(sizes_m: np.ndarray, texel: np.ndarray, width: int, height: int):
    """Shelf-pack rectangles (k, 2) metres at ``texel`` (k,) m/texel; offsets (k, 2) or None."""
    # rounded before the ceiling: many sizes are whole numbers of texels, and the last bit of a
    # division (which differs between machines' SIMD paths) must not add a texel on one machine
    px = np.ceil(np.round(sizes_m / texel[:, None], 6)).astype(int) + 2 * PAD
    order = sorted(range(len(px)), key=lambda i: (-px[i, 1], -px[i, 0], i))
    offsets = np.zeros((len(px), 2), int)
    x = y = row_h = 0
    for i in order:
        w, h = px[i]
        if w > width:
            return None
        if x + w > width:
            x, y, row_h = 0, y + row_h, 0
        if y + h > height:
            return None
        offsets[i] = (x + PAD, y + PAD)
        x += w
        row_h = max(row_h, h)
    return offsets


def layout(patches: list[Patch], width: int, height: int, texel: float):
    """Smallest texel size >= ``texel`` (in 2 % steps) at which all patches fit the atlas."""
    sizes = np.array([p.size for p in patches])
    coarse = np.array([p.coarse for p in patches])
    for _ in range(400):
        offsets = pack(sizes, texel * coarse, width, height)
        if offsets is not None:
            return offsets, texel
        texel *= 1.02
    raise RuntimeError("patches do not fit the atlas; enlarge it")


def write_obj(path: Path, patches: list[Patch], offsets: np.ndarray, texel: float,
              width: int, height: int, mtl_name: str) -> None:
    """Write an OBJ with positions, UVs (OBJ convention: v = 0 at the image's bottom row) and
    normals; one texture region per patch."""
    lines = [f"# {path.name}: generated by scenes/make_assets.py, do not edit",
             f"# texel {texel * 1000:.3f} mm, atlas {width}x{height}", f"o {mtl_name}"]
    v_lines, vt_lines, vn_lines, f_lines = [], [], [], []
    base = 1
    for p, off in zip(patches, offsets, strict=True):
        uv_px = off + p.local / (texel * p.coarse)
        u = uv_px[:, 0] / width
        v = 1.0 - uv_px[:, 1] / height
        for q in p.positions:
            v_lines.append(f"v {q[0]:.6f} {q[1]:.6f} {q[2]:.6f}")
        for a, b in zip(u, v, strict=True):
            vt_lines.append(f"vt {a:.6f} {b:.6f}")
        for nrm in p.normals:
            vn_lines.append(f"vn {nrm[0]:.6f} {nrm[1]:.6f} {nrm[2]:.6f}")
        for t in p.triangles + base:
            f_lines.append("f " + " ".join(f"{i}/{i}/{i}" for i in t))
        base += len(p.positions)
    path.write_text("\n".join(lines + v_lines + vt_lines + vn_lines + f_lines) + "\n")


# --------------------------------------------------------------------------------------------
# Textures
# --------------------------------------------------------------------------------------------


def _noise(rng: np.random.Generator, h: int, w: int, cells: float, c: int) -> np.ndarray:
    """Smooth value noise (h, w, c) in about [0, 1] with ``cells`` cells across the width."""
    gw = max(2, int(round(cells)))
    gh = max(2, int(round(cells * h / w)))
    g = rng.random((gh, gw, c)).astype(np.float32)
    return cv2.resize(g, (w, h), interpolation=cv2.INTER_CUBIC).reshape(h, w, c)


def make_texture(seed: int, width: int, height: int, density: float = 1.0,
                 saturation: float = 1.0) -> np.ndarray:
    """A rich, non-repeating RGB texture (height, width, 3) uint8.

    Colour noise blended from a part-specific palette, modulated by mid-frequency luminance
    noise, under random anti-aliased ellipses (radius 1.5 - 30 texels, log-uniform) and short
    polyline strokes. ``density`` scales the number of blobs and strokes; ``saturation`` < 1
    mutes the colours toward a warm grey (the background, so that objects stand out on it).
    """
    rng = np.random.default_rng(seed)
    palette = rng.uniform(0.1, 0.95, (4, 3)).astype(np.float32)
    weights = _noise(rng, height, width, 5, 4) ** 3
    weights /= weights.sum(-1, keepdims=True)
    img = weights @ palette
    img *= 0.7 + 0.6 * _noise(rng, height, width, width / 16, 1)
    img = np.clip(img * 255, 0, 255).astype(np.uint8)
    img = np.ascontiguousarray(img)
    for _ in range(int(density * width * height / 250)):
        centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
        r = float(np.exp(rng.uniform(np.log(1.5), np.log(30.0))))
        axes = (max(1, int(r)), max(1, int(r * rng.uniform(0.3, 1.0))))
        if rng.random() < 0.5:  # half the blobs take a shade of the part's own palette
            col = palette[rng.integers(0, 4)] * 255 * rng.uniform(0.4, 1.3)
        else:
            col = rng.integers(0, 256, 3)
        colour = tuple(int(np.clip(v, 0, 255)) for v in col)
        cv2.ellipse(img, centre, axes, float(rng.uniform(0, 180)), 0, 360, colour, -1,
                    cv2.LINE_AA)
    for _ in range(int(density * width * height / 3000)):
        steps = rng.normal(0, 8, (int(rng.integers(2, 6)), 2))
        pts = np.cumsum(steps, 0) + rng.uniform(0, [width, height])
        colour = tuple(int(v) for v in rng.integers(0, 256, 3))
        cv2.polylines(img, [pts.astype(np.int32)], False, colour, int(rng.integers(1, 4)),
                      cv2.LINE_AA)
    if saturation != 1.0:
        grey = img.astype(np.float32).mean(-1, keepdims=True) * np.float32([1.05, 0.98, 0.88])
        img = np.clip(grey + saturation * (img - grey), 0, 255).astype(np.uint8)
    return img


# --------------------------------------------------------------------------------------------
# Parts. Object frames: z = 0 is the table top, the object's root body sits at the table centre.
# --------------------------------------------------------------------------------------------


def pliers_half(side: float, z0: float, z1: float) -> list[Patch]:
    """One half of a pair of pliers lying on the table, pivot at the origin, jaws along +x.

    ``side`` = -1: jaw on -y, handle on +y (the fixed half); +1: mirrored (the moving half).
    About 20 cm from jaw tip to handle end; handles 14 mm wide with a 3 mm thicker grip.
    """
    s = side
    out = cylinder((0.0, 0.0, (z0 + z1) / 2), 0.012, (z1 - z0) / 2)
    out += bar((0.006, s * 0.0045), (0.068, s * 0.0025), 0.009, z0, z1)  # jaw
    out += bar((-0.006, -s * 0.004), (-0.050, -s * 0.011), 0.012, z0, z1)  # handle neck
    grip_z0 = max(z0 - 0.0015, 0.0005)
    out += bar((-0.050, -s * 0.011), (-0.132, -s * 0.019), 0.015, grip_z0, z1 + 0.0015)  # grip
    return out


def truck_chassis() -> list[Patch]:
    """Chassis, cab and four wheels of a toy dump truck (about 30 x 14 x 17 cm), +x forward."""
    out = box((-0.14, -0.05, 0.045), (0.14, 0.05, 0.07))  # frame
    out += box((0.06, -0.065, 0.07), (0.15, 0.065, 0.17))  # cab
    out += box((0.14, -0.07, 0.035), (0.155, 0.07, 0.06))  # front bumper
    for x in (0.09, -0.08):
        for y in (0.065, -0.065):
            out += cylinder((x, y, 0.0355), 0.035, 0.015, axis="y")
    return out


def truck_bed() -> list[Patch]:
    """Open dump bed, 20.5 x 14 x 7.8 cm, 6 mm walls, with a lip over the cab to pull on."""
    x0, x1, y, z0, z1, t = -0.15, 0.055, 0.07, 0.072, 0.15, 0.006
    out = box((x0, -y, z0), (x1, y, z0 + 0.008))  # floor
    out += box((x0, -y, z0 + 0.008), (x1, -y + t, z1))  # right wall
    out += box((x0, y - t, z0 + 0.008), (x1, y, z1))  # left wall
    out += box((x0, -y + t, z0 + 0.008), (x0 + t, y - t, z1 - 0.02))  # tailgate (lower)
    out += box((x1 - t, -y + t, z0 + 0.008), (x1, y - t, z1))  # front wall
    out += box((x1, -0.05, z1 - 0.008), (x1 + 0.04, 0.05, z1))  # lip over the cab
    return out


def cabinet() -> list[Patch]:
    """A 24 x 30 x 30 cm cabinet, front at +x, a drawer opening at the top, 12 mm panels."""
    x0, x1, y, h, t = -0.12, 0.12, 0.15, 0.30, 0.012
    z0 = 0.0005
    out = box((x0, -y, z0), (x1, y, z0 + t), skip=("-z",))  # bottom
    out += box((x0, -y, h - t), (x1, y, h))  # top
    out += box((x0, -y, z0 + t), (x1, -y + t, h - t))  # right side
    out += box((x0, y - t, z0 + t), (x1, y, h - t))  # left side
    out += box((x0, -y + t, z0 + t), (x0 + t, y - t, h - t))  # back
    out += box((x0 + t, -y + t, 0.158), (x1, y - t, 0.17))  # shelf under the drawer
    out += box((x1 - t, -y + t, z0 + t), (x1, y - t, 0.158))  # fixed front below the drawer
    return out


def drawer() -> list[Patch]:
    """Drawer (front 27.2 x 11.3 cm, tray 20.8 cm deep) with a bar handle, closed position."""
    out = box((0.108, -0.136, 0.173), (0.12, 0.136, 0.286))  # front
    out += box((-0.10, -0.13, 0.174), (0.108, 0.13, 0.18))  # tray bottom
    out += box((-0.10, -0.13, 0.18), (0.108, -0.124, 0.26))  # tray right
    out += box((-0.10, 0.124, 0.18), (0.108, 0.13, 0.26))  # tray left
    out += box((-0.10, -0.124, 0.18), (-0.094, 0.124, 0.26))  # tray back
    for yy in (-0.05, 0.05):
        out += box((0.12, yy - 0.006, 0.224), (0.14, yy + 0.006, 0.236))  # handle posts
    out += box((0.14, -0.06, 0.222), (0.152, 0.06, 0.238))  # handle bar
    return out


def table() -> list[Patch]:
    """Round table: top radius 0.35 m, 4 cm thick (top face at z = 0.45), one leg."""
    top = cylinder((0.0, 0.0, 0.43), 0.35, 0.02, pieces=4, coarse=(1.0, 4.0, 1.0))
    return top + cylinder((0.0, 0.0, 0.21), 0.05, 0.21, caps=(False, False), coarse=(4, 4, 4))


def floor() -> list[Patch]:
    """Floor square 4 x 4 m at z = 0 (only its top face)."""
    return [quad([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]])]


def walls() -> list[Patch]:
    """Four walls 2.2 m high around the floor (inner faces only)."""
    h = 2.2
    return [
        quad([[-2, -2, 0], [-2, 2, 0], [-2, 2, h], [-2, -2, h]]),
        quad([[2, 2, 0], [2, -2, 0], [2, -2, h], [2, 2, h]]),
        quad([[2, -2, 0], [-2, -2, 0], [-2, -2, h], [2, -2, h]]),
        quad([[-2, 2, 0], [2, 2, 0], [2, 2, h], [-2, 2, h]]),
    ]


# Parts of the scenes of the method's wider object set (scissors, Barrett hand, scraper truck,
# hinged cabinet). Appended after the first scenes' parts; they do not change those parts' output.


def scissors_half(side: float, z0: float, z1: float) -> list[Patch]:
    """One half of a pair of scissors lying on the table, pivot at the origin, blade along +x.

    ``side`` = -1: blade edge on -y, handle ring on +y (the fixed half); +1: mirrored (the
    moving half). 18 cm from blade tip to the end of the ring; blade 14 -> 6 mm wide; the
    finger ring is a 48 x 28 mm frame of 6 mm bars (the place to pull on).
    """
    s = side
    out = cylinder((0.0, 0.0, (z0 + z1) / 2), 0.009, (z1 - z0) / 2)
    out += bar((0.006, s * 0.002), (0.050, s * 0.003), 0.014, z0, z1)  # blade root
    out += bar((0.050, s * 0.003), (0.088, s * 0.001), 0.007, z0, z1)  # blade tip
    out += bar((-0.006, -s * 0.003), (-0.040, -s * 0.012), 0.009, z0, z1)  # handle neck
    cx, cy, hx, hy, w = -0.066, -s * 0.020, 0.026, 0.014, 0.006
    out += box((cx - hx, cy - hy, z0), (cx + hx, cy - hy + w, z1))  # ring, side near -y
    out += box((cx - hx, cy + hy - w, z0), (cx + hx, cy + hy, z1))  # ring, side near +y
    out += box((cx - hx, cy - hy + w, z0), (cx - hx + w, cy + hy - w, z1))  # ring, far end
    out += box((cx + hx - w, cy - hy + w, z0), (cx + hx, cy + hy - w, z1))  # ring, near end
    return out


#: Barrett hand layout (metres, object frame): palm a cylinder on the table, the fixed finger
#: (F3) at -x, the two spreading fingers (F1 at +y, F2 at -y) at +x, all curling inwards.
BARRETT_PALM_RADIUS = 0.055
BARRETT_PALM_TOP = 0.075
BARRETT_FINGER_BASES = {"f3": (-0.032, 0.0), "f1": (0.026, 0.026), "f2": (0.026, -0.026)}


def barrett_finger(base_x: float, base_y: float, inward: float) -> list[Patch]:
    """One finger standing on the palm at (base_x, base_y): a knuckle block, a 6 cm proximal
    link straight up and a 4 cm distal link bent over towards ``inward`` (+1: +x, -1: -x)."""
    t = BARRETT_PALM_TOP
    out = box((base_x - 0.013, base_y - 0.012, t), (base_x + 0.013, base_y + 0.012, t + 0.014),
              skip=("-z",))  # knuckle
    out += box((base_x - 0.009, base_y - 0.010, t + 0.014), (base_x + 0.009, base_y + 0.010,
                                                             t + 0.074))  # proximal
    x_in = base_x + inward * 0.009
    x_tip = base_x + inward * 0.047
    out += box((min(x_in, x_tip), base_y - 0.009, t + 0.060),
               (max(x_in, x_tip), base_y + 0.009, t + 0.074))  # distal, bent over
    return out


def barrett_palm() -> list[Patch]:
    """Palm (cylinder 11 cm across, 7.5 cm high) with the fixed finger F3 on top."""
    out = cylinder((0.0, 0.0, BARRETT_PALM_TOP / 2 + 0.00025), BARRETT_PALM_RADIUS,
                   BARRETT_PALM_TOP / 2 - 0.00025, caps=(False, True), pieces=2)
    x, y = BARRETT_FINGER_BASES["f3"]
    return out + barrett_finger(x, y, +1.0)


def scraper_chassis() -> list[Patch]:
    """Chassis, cab and four wheels of a toy scraper (grader) truck, 25 x 17 x 17 cm, +x forward."""
    out = box((-0.13, -0.06, 0.04), (0.06, 0.06, 0.09))  # body
    out += box((-0.11, -0.05, 0.09), (-0.03, 0.05, 0.17))  # cab
    out += box((-0.02, -0.03, 0.09), (0.02, 0.03, 0.094))  # boom mount plate
    for x in (-0.09, 0.025):
        for y in (0.072, -0.072):
            out += cylinder((x, y, 0.0355), 0.035, 0.012, axis="y")
    return out


def scraper_boom() -> list[Patch]:
    """Boom: a 3 x 2 cm beam from its pivot on the chassis to 16 cm forward."""
    return box((-0.012, -0.015, 0.094), (0.168, 0.015, 0.114))


def scraper_blade() -> list[Patch]:
    """Blade (18 x 9 cm, 8 mm thick) hanging from a bracket at the boom's front end."""
    out = box((0.168, -0.02, 0.090), (0.180, 0.02, 0.118))  # bracket around the pivot
    out += box((0.180, -0.09, 0.014), (0.188, 0.09, 0.118))  # blade plate
    return out


#: Hinged cabinet (metres, object frame): 24 deep, 30 wide, 32 high, front at +x, a door over
#: the lower compartment (hinge on the front's -y edge) and a drawer above the shelf.
HCAB_X, HCAB_Y, HCAB_H, HCAB_T, HCAB_SHELF = 0.12, 0.15, 0.32, 0.012, 0.20


def hinged_cabinet() -> list[Patch]:
    """Carcass of the hinged cabinet: 12 mm panels, a shelf between door and drawer."""
    x0, x1, y, h, t, sh = -HCAB_X, HCAB_X, HCAB_Y, HCAB_H, HCAB_T, HCAB_SHELF
    z0 = 0.0005
    out = box((x0, -y, z0), (x1, y, z0 + t), skip=("-z",))  # bottom
    out += box((x0, -y, h - t), (x1, y, h))  # top
    out += box((x0, -y, z0 + t), (x1, -y + t, h - t))  # right side
    out += box((x0, y - t, z0 + t), (x1, y, h - t))  # left side
    out += box((x0, -y + t, z0 + t), (x0 + t, y - t, h - t))  # back
    out += box((x0 + t, -y + t, sh), (x1, y - t, sh + t))  # shelf
    return out


def hinged_cabinet_door() -> list[Patch]:
    """Door of the lower compartment (27.4 x 18.6 cm) with a vertical bar handle at its free
    edge (+y), closed."""
    x1, y, t = HCAB_X, HCAB_Y - HCAB_T - 0.001, HCAB_T
    out = box((x1 - t, -y, 0.0135), (x1, y, HCAB_SHELF - 0.001))  # panel
    for z in (0.07, 0.14):
        out += box((x1, 0.100, z - 0.006), (x1 + 0.016, 0.112, z + 0.006))  # handle posts
    out += box((x1 + 0.016, 0.098, 0.055), (x1 + 0.028, 0.114, 0.155))  # handle bar
    return out


def hinged_cabinet_drawer() -> list[Patch]:
    """Drawer above the shelf (front 27.4 x 9.4 cm, tray 20.8 cm deep), bar handle, closed."""
    x1, y, t = HCAB_X, HCAB_Y - HCAB_T - 0.001, HCAB_T
    z0, z1 = HCAB_SHELF + t + 0.001, HCAB_H - t - 0.001
    out = box((x1 - t, -y, z0), (x1, y, z1))  # front
    out += box((-0.10, -0.13, z0 + 0.001), (x1 - t, 0.13, z0 + 0.007))  # tray bottom
    out += box((-0.10, -0.13, z0 + 0.007), (x1 - t, -0.124, z1 - 0.02))  # tray right
    out += box((-0.10, 0.124, z0 + 0.007), (x1 - t, 0.13, z1 - 0.02))  # tray left
    out += box((-0.10, -0.124, z0 + 0.007), (-0.094, 0.124, z1 - 0.02))  # tray back
    zc = (z0 + z1) / 2
    for yy in (-0.05, 0.05):
        out += box((x1, yy - 0.006, zc - 0.006), (x1 + 0.02, yy + 0.006, zc + 0.006))  # posts
    out += box((x1 + 0.02, -0.06, zc - 0.008), (x1 + 0.032, 0.06, zc + 0.008))  # handle bar
    return out


@dataclass(frozen=True)
class Part:
    """One generated asset: ``<name>.obj`` and ``<name>.png``."""

    name: str
    build: object  # () -> list[Patch]
    width: int  # atlas size in texels
    height: int
    texel: float  # wanted texel size, metres; grown until the patches fit
    density: float = 1.0  # blobs per area, relative
    saturation: float = 1.0  # colour saturation, relative (background parts are muted)


PARTS = (
    Part("pliers_fixed", lambda: pliers_half(-1.0, 0.0005, 0.0085), 256, 256, 0.0005),
    Part("pliers_moving", lambda: pliers_half(+1.0, 0.0095, 0.0175), 256, 256, 0.0005),
    Part("truck_chassis", truck_chassis, 768, 768, 0.0008),
    Part("truck_bed", truck_bed, 512, 512, 0.0008),
    Part("cabinet", cabinet, 1024, 1024, 0.0012),
    Part("drawer", drawer, 768, 512, 0.0010),
    Part("table", table, 1024, 1024, 0.0009, saturation=0.4),
    Part("floor", floor, 768, 768, 0.004, density=0.7, saturation=0.5),
    Part("walls", walls, 1024, 1024, 0.006, density=0.7, saturation=0.5),
    Part("scissors_fixed", lambda: scissors_half(-1.0, 0.0005, 0.0045), 256, 256, 0.0005),
    Part("scissors_moving", lambda: scissors_half(+1.0, 0.0050, 0.0090), 256, 256, 0.0005),
    Part("barrett_palm", barrett_palm, 512, 512, 0.0008),
    Part("barrett_finger1", lambda: barrett_finger(*BARRETT_FINGER_BASES["f1"], -1.0),
         256, 256, 0.0007),
    Part("barrett_finger2", lambda: barrett_finger(*BARRETT_FINGER_BASES["f2"], -1.0),
         256, 256, 0.0007),
    Part("scraper_chassis", scraper_chassis, 768, 768, 0.0008),
    Part("scraper_boom", scraper_boom, 256, 512, 0.0008),
    Part("scraper_blade", scraper_blade, 512, 256, 0.0008),
    Part("hinged_cabinet", hinged_cabinet, 1024, 1024, 0.0012),
    Part("hinged_cabinet_door", hinged_cabinet_door, 512, 512, 0.0010),
    Part("hinged_cabinet_drawer", hinged_cabinet_drawer, 768, 512, 0.0010),
)


def part_seed(seed: int, name: str) -> int:
    """Seed of one part: stable across runs, platforms and the order of PARTS."""
    return int(np.random.SeedSequence([seed, zlib.crc32(name.encode())]).generate_state(1)[0])


def generate(out_dir: Path, seed: int = SEED) -> dict[str, float]:
    """Write every part's OBJ and PNG into ``out_dir``; returns the texel size (m) per part."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    texels = {}
    for part in PARTS:
        patches = part.build()
        offsets, texel = layout(patches, part.width, part.height, part.texel)
        write_obj(out_dir / f"{part.name}.obj", patches, offsets, texel, part.width,
                  part.height, part.name)
        img = make_texture(part_seed(seed, part.name), part.width, part.height, part.density,
                           part.saturation)
        cv2.imwrite(str(out_dir / f"{part.name}.png"), img[..., ::-1],
                    [cv2.IMWRITE_PNG_COMPRESSION, 9])
        texels[part.name] = texel
    return texels


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=HERE / "assets", help="output folder")
    parser.add_argument("--seed", type=int, default=SEED, help="master seed")
    args = parser.parse_args()
    texels = generate(args.out, args.seed)
    total = 0
    for part in PARTS:
        size = sum((args.out / f"{part.name}.{ext}").stat().st_size for ext in ("obj", "png"))
        total += size
        print(f"{part.name:15s} atlas {part.width}x{part.height}  "
              f"texel {texels[part.name] * 1000:5.2f} mm  {size / 1e6:5.2f} MB")
    print(f"total {total / 1e6:.2f} MB in {args.out}")


if __name__ == "__main__":
    main()
