"""Texture check: does every part of the object show enough texture for SIFT features?

SfM and the matching between the two configurations feed on SIFT features; a part whose surface
is plain (an imported mesh with a flat colour, a primitive without a texture) gives none, and the
reconstruction fails after minutes of capture and SfM without saying why. This check renders a
few views of the scene with :mod:`sim.render` (no arm involved: free cameras around the object at
the capture's distance, in both configurations), and measures per part (object link) the share of
its image area that is *textured*: where the smaller eigenvalue of the image's structure tensor
(Shi-Tomasi's corner measure, the local 2-D intensity variation SIFT's detector and descriptor
need) exceeds a threshold. A part below :attr:`TextureCheckConfig.min_textured_share` raises
:class:`TextureError` naming it and saying how to fix it. A part none of whose visible geoms has a
UV-mapped texture is refused at once, before rendering (flat colour cannot pass). It takes
about 10 s (8 renders) on a 2-core machine without GPU; the refusal of an untextured part about
as long as compiling the scene.

``python -m sim.evaluate`` runs it before capturing; ``python -m sim.author import`` after
writing a scene. ``check_texture(load_scene(path)).summary()`` prints the figures.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import mujoco
import numpy as np

from sim.camera import intrinsics_matrix
from sim.views import object_bounding_sphere, ring_distance

log = logging.getLogger(__name__)


class TextureError(ValueError):
    """A part of a scene's object is too plain for features; the message names it and the fix."""


@dataclass(frozen=True)
class TextureCheckConfig:
    """Settings of :func:`check_texture`."""

    azimuths: int = 4
    """views per configuration, evenly spread in azimuth (B's turned half a step from A's)"""
    elevation_deg: float = 35.0
    """elevation of the views above the object's centre (the capture's rings lie at 20 - 70
    deg); with 4 azimuths, 8 views in all: about 0.7 s each on a 2-core machine without GPU"""
    fill: float = 0.6
    """diameter of the object's bounding sphere as a share of the shorter image side (the
    capture's preferred fill, sim.views.ViewPlanConfig.fill)"""
    width: int = 640
    """image width (px), as the wrist camera's"""
    height: int = 480
    """image height (px)"""
    fx: float = 554.0
    """focal length (px), as the wrist camera's"""
    block: int = 7
    """window (px) of the structure tensor: about the scale of SIFT's smallest keypoints"""
    min_eigenvalue: float = 10.0
    """threshold on the tensor's smaller eigenvalue (grey levels^2, cv2.cornerMinEigenVal with a
    3 px Sobel). Measured on 8 views each (tests/test_texture_check.py keeps these): the
    bundled parts have 52 - 93 % of their area above it (Barrett fingers least), the same parts
    with their textures removed 4 - 25 % (thin parts most: their edges)"""
    erode: int = 4
    """pixels taken off each part's silhouette (its outline against the background is an edge
    of the view, not texture of the part)"""
    min_textured_share: float = 0.4
    """least share of a part's image area that must be textured: between the figures above"""
    min_pixels: int = 200
    """a part seen by fewer pixels in all views together is not judged (too small to matter or
    always hidden)"""


@dataclass(frozen=True)
class PartTexture:
    """Figures of one part."""

    link: str
    """the object link (its root body's name)"""
    pixels: int
    """its image area over all views (px, after erosion)"""
    textured_share: float
    """share of that area with enough texture"""
    geoms: tuple[str, ...]
    """its visible geoms (names, or ``geom N``)"""
    untextured_geoms: tuple[str, ...]
    """those without a UV-mapped 2D texture"""


@dataclass(frozen=True)
class TextureReport:
    """Result of :func:`check_texture`."""

    scene: str
    parts: tuple[PartTexture, ...]
    views: int
    config: TextureCheckConfig

    def summary(self) -> str:
        """One line per part."""
        lines = [f"texture check of {self.scene} ({self.views} views): textured share of each "
                 f"part's image area (need {self.config.min_textured_share:.0%})"]
        for p in self.parts:
            lines.append(f"  {p.link:24s} {p.textured_share:6.1%} of {p.pixels} px")
        return "\n".join(lines)

    @property
    def failing(self) -> tuple[PartTexture, ...]:
        """Parts judged too plain."""
        c = self.config
        return tuple(p for p in self.parts if p.pixels >= c.min_pixels
                     and p.textured_share < c.min_textured_share)


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """T_world_camera (OpenCV: x right, y down, z forward) at ``eye`` looking at ``target``."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-9:
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.c_[x, np.cross(z, x), z]
    T[:3, 3] = eye
    return T


def _geom_name(model, g: int) -> str:
    return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom {g}"


def textured_mask(rgb: np.ndarray, config: TextureCheckConfig = TextureCheckConfig()
                  ) -> np.ndarray:
    """Pixels (h, w) bool with enough local 2-D texture for features (see the module)."""
    grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY).astype(np.float32)
    lam = cv2.cornerMinEigenVal(grey, config.block, 3)
    return lam > config.min_eigenvalue


def check_texture(scene, config: TextureCheckConfig = TextureCheckConfig(),
                  raise_on_failure: bool = True) -> TextureReport:
    """Render a few views of ``scene`` and measure how textured each object link looks.

    Parameters
    ----------
    scene : sim.scene.Scene
    config : TextureCheckConfig
    raise_on_failure : bool
        Raise :class:`TextureError` for a part below the threshold (else only report).

    Returns
    -------
    TextureReport

    Raises
    ------
    TextureError
        A part is too plain; the message names it, its figure and the fix.
    """
    model = scene.model
    link_of = {b: i for i, li in enumerate(scene.links) for b in li.body_ids}
    labels = np.full(model.ngeom, -3, dtype=np.int64)
    geoms: dict[int, list[int]] = {i: [] for i in range(len(scene.links))}
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        if b in link_of:
            labels[g] = link_of[b]
            if int(model.geom_group[g]) <= 2:
                geoms[link_of[b]].append(g)
    untextured = {i: tuple(_geom_name(model, g) for g in geoms[i] if not _textured(model, g))
                  for i in geoms}
    bare = [i for i in geoms if geoms[i] and len(untextured[i]) == len(geoms[i])]
    if raise_on_failure and bare:
        # a part without any UV-mapped texture can only show flat colour and shading: refused
        # at once, before any rendering
        parts = tuple(PartTexture(scene.links[i].name, 0, 0.0, untextured[i], untextured[i])
                      for i in bare)
        raise TextureError(_message(scene, TextureReport(scene.name, parts, 0, config), parts))
    from sim import render  # pyrender (1 s, needs EGL): only to render

    K = intrinsics_matrix(config.fx, config.fx, (config.width - 1) / 2, (config.height - 1) / 2)
    renderer = render.MjRenderer(model, geom_labels=labels)
    kernel = np.ones((2 * config.erode + 1, 2 * config.erode + 1), np.uint8)
    area = np.zeros(len(scene.links))
    textured = np.zeros(len(scene.links))
    n_views = 0
    el = np.deg2rad(config.elevation_deg)
    for shift, configuration in enumerate(("a", "b")):
        data = scene.make_data(configuration)
        centre, radius = object_bounding_sphere(model, data)
        distance = ring_distance(radius, K, config.width, config.height, config.fill)
        for k in range(config.azimuths):
            az = 2 * np.pi * (k + 0.5 * shift) / config.azimuths
            eye = centre + distance * np.array([np.cos(el) * np.cos(az),
                                                np.cos(el) * np.sin(az), np.sin(el)])
            out = renderer.render(data, K, _look_at(eye, centre), config.width, config.height,
                                  labels=True)
            tex = textured_mask(out.color, config)
            for i in range(len(scene.links)):
                mask = cv2.erode((out.labels == i).astype(np.uint8), kernel) > 0
                area[i] += mask.sum()
                textured[i] += (mask & tex).sum()
            n_views += 1
    parts = []
    for i, li in enumerate(scene.links):
        parts.append(PartTexture(li.name, int(area[i]),
                                 float(textured[i] / area[i]) if area[i] else 0.0,
                                 tuple(_geom_name(model, g) for g in geoms[i]), untextured[i]))
    report = TextureReport(scene.name, tuple(parts), n_views, config)
    log.info("%s", report.summary())
    if raise_on_failure and report.failing:
        raise TextureError(_message(scene, report, report.failing))
    return report


def _textured(model, g: int) -> bool:
    """Whether a visible geom carries a 2D texture mapped by texture coordinates."""
    mat = int(model.geom_matid[g])
    roles = (mujoco.mjtTextureRole.mjTEXROLE_RGB, mujoco.mjtTextureRole.mjTEXROLE_RGBA)
    if mat < 0 or all(int(model.mat_texid[mat, int(r)]) < 0 for r in roles):
        return False
    return not (int(model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_MESH)
                and int(model.mesh_texcoordnum[int(model.geom_dataid[g])]) == 0)


def _message(scene, report: TextureReport, failing) -> str:
    c = report.config
    how = (f"measured on {report.views} rendered views" if report.views else
           "without rendering: they have no texture at all")
    lines = [f"{scene.path}: too little texture for SIFT features on {len(failing)} part(s) of "
             f"the object, {how} (need {c.min_textured_share:.0%} of each part's image area "
             f"textured):"]
    for p in failing:
        why = (f"its geoms {list(p.untextured_geoms)} have no UV-mapped 2D texture"
               if p.untextured_geoms else "its texture is too plain or too coarse at the "
                                          "capture distance")
        figure = f"{p.textured_share:.0%} textured" if report.views else "untextured"
        lines.append(f"  part {p.link!r}: {figure} ({why})")
    lines.append(
        "fix: give every visible surface of the part its own non-repeating texture mapped by "
        "the mesh's UVs: import the object with `python -m sim.author import SOURCE --out DIR` "
        "(it textures every part), or texture a mesh with sim.assets.texture_mesh (bundled "
        "parts: scenes/make_assets.py); see scenes/README.md")
    return "\n".join(lines)
