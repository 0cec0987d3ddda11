"""Textured assets for scenes: UV-mapped meshes and non-repeating textures.

The machinery behind ``scenes/make_assets.py`` (the bundled scenes' assets) and
``python -m sim.author`` (imported objects), for anyone who wants to texture a mesh of their own
the way the harness needs it: every surface gets its own region of one texture atlas per part, so
no piece of texture appears twice anywhere in the world (a repeated pattern can make SfM fold a
ring of cameras), and the texture is rich at every scale (multi-scale colour noise under random
blobs and strokes: corners from about 2 to 60 texels, what SIFT needs).

Two ways to lay out an atlas:

- **patches** (:class:`Patch`, :func:`quad`, :func:`box`, :func:`bar`, :func:`cylinder`):
  pieces of surface with a planar parameterisation in metres, shelf-packed by :func:`layout`
  and written by :func:`write_obj`; what the bundled parts are built from;
- **any triangle mesh** (:func:`unwrap`): charts cut and packed by xatlas at a given texel size,
  written by :func:`write_uv_obj`. :func:`texture_mesh` does the whole job for one part: unwrap,
  texture, write ``NAME.obj`` and ``NAME.png``.

Textures come from :func:`make_texture` with a per-part seed (:func:`part_seed`: the master
seed and the part's name), so the output is deterministic. Example::

    from sim.assets import texture_mesh
    part = texture_mesh(vertices, faces, "out/assets", "lid", texel=0.001)
    # out/assets/lid.obj (positions, UVs, normals) and out/assets/lid.png

Geometry is in metres. Texel size: the capture camera (fx = 554 px) at about 0.4 m sees about
0.7 mm per pixel at the image centre, so object parts want 0.5 - 1.2 mm per texel
(:data:`OBJECT_TEXEL`), the background coarser.
"""

from __future__ import annotations

import logging
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import xatlas

log = logging.getLogger(__name__)

#: Master seed of every asset; change it to get a different (but again deterministic) world.
SEED = 2024
#: Blank border, in texels, around each face's region in an atlas (keeps mipmaps from mixing
#: neighbouring faces at the distances the camera sees them).
PAD = 3
#: Segments of a full circle for cylinders and disks (visual only; collisions use primitives).
SEGMENTS = 48
#: Texel size (m) an object part wants: about one texel per image pixel at the capture distance
#: (0.72 mm per pixel at 0.4 m, 1.4 mm per pixel for a 20 cm object filling half the image).
OBJECT_TEXEL = 0.001
#: Largest atlas side (texels) :func:`unwrap` makes before it coarsens the texel size instead:
#: 2048^2 RGB is 12 MB in memory and a few MB of PNG, the most a part should weigh.
MAX_ATLAS = 2048
#: Step by which :func:`unwrap` coarsens the texel size while the charts do not fit
#: :data:`MAX_ATLAS` (each try repacks every chart).
TEXEL_GROWTH = 1.15


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
    """Smallest texel size >= ``texel`` (in 2 % steps) at which all patches fit the atlas.

    Returns ``(offsets, texel)``: offsets (k, 2) int of each patch's region (texels, from the
    atlas's top-left corner) and the texel size (m) reached."""
    sizes = np.array([p.size for p in patches])
    coarse = np.array([p.coarse for p in patches])
    for _ in range(400):
        offsets = pack(sizes, texel * coarse, width, height)
        if offsets is not None:
            return offsets, texel
        texel *= 1.02
    raise ValueError(f"{len(patches)} patches do not fit a {width}x{height} atlas at any "
                     f"texel size up to {texel * 1000:.2f} mm; enlarge the atlas")


def write_obj(path: Path, patches: list[Patch], offsets: np.ndarray, texel: float,
              width: int, height: int, mtl_name: str, generator: str = "sim.assets") -> None:
    """Write an OBJ with positions, UVs (OBJ convention: v = 0 at the image's bottom row) and
    normals; one texture region per patch (``offsets`` (k, 2) int from :func:`layout`).
    ``generator`` names the program in the file's first comment line."""
    lines = [f"# {path.name}: generated by {generator}, do not edit",
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
# Parts: one OBJ and one PNG each
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Part:
    """One generated asset: ``<name>.obj`` and ``<name>.png``."""

    name: str
    """file stem, and the name the part's texture seed derives from"""
    build: Callable[[], list[Patch]]
    """returns the part's patches (metres, in the frame of the body that carries the mesh)"""
    width: int
    """atlas width in texels"""
    height: int
    """atlas height in texels"""
    texel: float
    """wanted texel size (m); grown in 2 % steps until the patches fit"""
    density: float = 1.0
    """blobs and strokes per area, relative"""
    saturation: float = 1.0
    """colour saturation, relative (background parts are muted)"""


def part_seed(seed: int, name: str) -> int:
    """Seed of one part: stable across runs, platforms and the order of the parts."""
    return int(np.random.SeedSequence([seed, zlib.crc32(name.encode())]).generate_state(1)[0])


def write_png(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB image (h, w, 3) uint8 as a maximally compressed PNG."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an RGB image (h, w, 3) uint8, got {rgb.shape} {rgb.dtype}")
    if not cv2.imwrite(str(path), rgb[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9]):
        raise OSError(f"could not write {path}")


def generate_parts(parts: Sequence[Part], out_dir: Path, seed: int = SEED,
                   generator: str = "sim.assets") -> dict[str, float]:
    """Write every part's OBJ and PNG into ``out_dir``; returns the texel size (m) per part."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    texels = {}
    for part in parts:
        patches = part.build()
        offsets, texel = layout(patches, part.width, part.height, part.texel)
        write_obj(out_dir / f"{part.name}.obj", patches, offsets, texel, part.width,
                  part.height, part.name, generator)
        img = make_texture(part_seed(seed, part.name), part.width, part.height, part.density,
                           part.saturation)
        write_png(out_dir / f"{part.name}.png", img)
        texels[part.name] = texel
    return texels


# --------------------------------------------------------------------------------------------
# Any triangle mesh: charts by xatlas
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UVMesh:
    """A triangle mesh with texture coordinates into one atlas (vertices split at chart seams).

    Attributes
    ----------
    positions : (n, 3) float
        Vertices (m).
    normals : (n, 3) float
        Unit vertex normals: area-weighted face normals of each vertex's chart.
    uv : (n, 2) float
        Texture coordinates in [0, 1], OBJ convention (v = 0 at the image's bottom row).
    faces : (m, 3) int
        Triangles, counter-clockwise seen from outside (as given).
    width, height : int
        Atlas size in texels.
    texel : float
        Texel size (m) of the layout.
    """

    positions: np.ndarray
    normals: np.ndarray
    uv: np.ndarray
    faces: np.ndarray
    width: int
    height: int
    texel: float


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
        raise ValueError(f"expected vertices of shape (n >= 3, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) < 1 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"expected integer faces of shape (m >= 1, 3), got {f.shape} {f.dtype}")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"faces index vertices {f.min()}..{f.max()}, but there are {len(v)}")
    if not np.all(np.isfinite(v)):
        raise ValueError("vertices contain NaN or infinity")
    return v, f.astype(np.int64)


def _face_normals(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unnormalised face normals (m, 3) (length = twice the area) and areas (m,)."""
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n, 0.5 * np.linalg.norm(n, axis=1)


#: Triangles smaller than this (m^2) carry no texture and would only upset the chart builder:
#: a 0.1 mm square, far below one texel.
MIN_FACE_AREA = 1e-8


def unwrap(vertices, faces, texel: float = OBJECT_TEXEL, max_size: int = MAX_ATLAS,
           padding: int = PAD) -> UVMesh:
    """Cut a triangle mesh into charts and pack them into one atlas (xatlas).

    Every triangle gets its own region of the atlas (charts never overlap, ``padding`` texels
    apart), at ``texel`` metres per texel, coarsened by :data:`TEXEL_GROWTH` steps while the
    atlas would exceed ``max_size`` texels a side. Degenerate triangles (area below
    :data:`MIN_FACE_AREA`) are dropped.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions (m).
    faces : (m, 3) int
        Triangles.
    texel : float
        Wanted texel size (m).
    max_size : int
        Largest atlas side (texels).
    padding : int
        Blank texels around each chart.

    Returns
    -------
    UVMesh
    """
    v, f = _check_mesh(vertices, faces)
    if not texel > 0:
        raise ValueError(f"texel must be positive, got {texel}")
    fn, area = _face_normals(v, f)
    keep = area > MIN_FACE_AREA
    if not keep.any():
        raise ValueError(f"every one of the {len(f)} triangles is degenerate (area below "
                         f"{MIN_FACE_AREA:g} m^2): nothing to texture")
    f, fn = f[keep], fn[keep]
    pos32 = np.ascontiguousarray(v, dtype=np.float32)
    idx32 = np.ascontiguousarray(f, dtype=np.uint32)
    chart = xatlas.ChartOptions()
    for _ in range(60):
        pack = xatlas.PackOptions()
        pack.padding = int(padding)
        pack.texels_per_unit = float(1.0 / texel)
        pack.resolution = 0
        pack.bilinear = True
        count, width, height, charted = _generate_atlas(pos32, idx32, chart, pack)
        if count == 1 and max(width, height) <= max_size:
            break
        texel *= max(TEXEL_GROWTH, max(width, height) / max_size)
    else:
        raise ValueError(f"the mesh does not fit a {max_size}x{max_size} atlas")
    vmap, out_faces, uv = charted
    vmap = np.asarray(vmap, dtype=np.int64)
    out_faces = np.asarray(out_faces, dtype=np.int64)
    # xatlas keeps the triangle order and winding; normals per output vertex from its faces
    normals = np.zeros((len(vmap), 3))
    for k in range(3):
        np.add.at(normals, out_faces[:, k], fn)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > 0, normals / np.maximum(length, 1e-300), [0.0, 0.0, 1.0])
    uv = np.asarray(uv, dtype=float)
    uv = np.c_[uv[:, 0], 1.0 - uv[:, 1]]  # xatlas: rows from the top; OBJ: v up
    return UVMesh(v[vmap], normals, uv, out_faces, int(width), int(height), float(texel))


#: Seconds an xatlas atlas is kept after its charts are read, before it is destroyed (below).
XATLAS_SETTLE_S = 0.05


def _generate_atlas(positions: np.ndarray, indices: np.ndarray, chart, pack):
    """One xatlas run: ``(atlas_count, width, height, (vmap, faces, uv) of the first mesh)``,
    copied out of the atlas.

    xatlas's task scheduler (0.0.11) wakes its worker threads without holding their mutex, so a
    worker still on its way back to sleep when the atlas is destroyed misses the shutdown call
    and the destructor's join waits for ever (seen once in CI: a test stopped in
    ``xatlas::Destroy`` for over 20 minutes, both threads idle). Every run of ``generate`` wakes
    the workers; waiting a few tens of milliseconds after it, while they go back to sleep, before
    the destructor runs closes that window in practice (it cannot be closed from outside xatlas).
    """
    atlas = xatlas.Atlas()
    atlas.add_mesh(positions, indices)
    atlas.generate(chart, pack)
    vmap, faces, uv = (np.array(a) for a in atlas[0])
    out = (int(atlas.atlas_count), int(atlas.width), int(atlas.height), (vmap, faces, uv))
    time.sleep(XATLAS_SETTLE_S)
    del atlas
    return out


def write_uv_obj(path: Path, mesh: UVMesh, name: str, generator: str = "sim.assets") -> None:
    """Write a :class:`UVMesh` as an OBJ with positions, UVs and normals."""
    path = Path(path)
    lines = [f"# {path.name}: generated by {generator}, do not edit",
             f"# texel {mesh.texel * 1000:.3f} mm, atlas {mesh.width}x{mesh.height}", f"o {name}"]
    lines += [f"v {q[0]:.6f} {q[1]:.6f} {q[2]:.6f}" for q in mesh.positions]
    lines += [f"vt {a:.6f} {b:.6f}" for a, b in mesh.uv]
    lines += [f"vn {n[0]:.6f} {n[1]:.6f} {n[2]:.6f}" for n in mesh.normals]
    lines += ["f " + " ".join(f"{i}/{i}/{i}" for i in t) for t in mesh.faces + 1]
    path.write_text("\n".join(lines) + "\n")


@dataclass(frozen=True)
class TexturedPart:
    """Files and layout of one part textured by :func:`texture_mesh`."""

    obj: Path
    """the OBJ (positions, UVs, normals)"""
    png: Path
    """its texture"""
    texel: float
    """texel size reached (m)"""
    width: int
    """atlas width (texels)"""
    height: int
    """atlas height (texels)"""


def texture_mesh(vertices, faces, out_dir: Path, name: str, *, texel: float = OBJECT_TEXEL,
                 seed: int = SEED, density: float = 1.0, saturation: float = 1.0,
                 generator: str = "sim.assets") -> TexturedPart:
    """Unwrap a mesh and give it its own non-repeating texture: ``OUT/NAME.obj``, ``NAME.png``.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions (m), in the frame of the body that will carry the mesh.
    faces : (m, 3) int
        Triangles, counter-clockwise seen from outside.
    out_dir : path
        Folder for the two files (created).
    name : str
        File stem; with ``seed`` it fixes the texture (:func:`part_seed`).
    texel : float
        Wanted texel size (m), see :func:`unwrap`.
    seed : int
        Master seed.
    density, saturation : float
        As :func:`make_texture`.
    generator : str
        Program named in the OBJ's first line.

    Returns
    -------
    TexturedPart
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    mesh = unwrap(vertices, faces, texel)
    obj, png = out_dir / f"{name}.obj", out_dir / f"{name}.png"
    write_uv_obj(obj, mesh, name, generator)
    write_png(png, make_texture(part_seed(seed, name), mesh.width, mesh.height, density,
                                saturation))
    log.debug("%s: %d triangles, atlas %dx%d, texel %.2f mm", name, len(mesh.faces),
              mesh.width, mesh.height, mesh.texel * 1000)
    return TexturedPart(obj, png, mesh.texel, mesh.width, mesh.height)
