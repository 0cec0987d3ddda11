"""Offscreen rendering of a MuJoCo scene with pyrender: colour, and for scoring depth and labels.

The pyrender scene is built once from a compiled :class:`mujoco.MjModel` (one node per visible
geom: primitives, meshes with their texture coordinates, planes as large textured quads, lights);
each frame only moves the nodes to the geom poses in :class:`mujoco.MjData`. Cameras are given as
OpenCV intrinsics ``K`` and an OpenCV pose ``T_world_camera``; the conversion to OpenGL goes
through :func:`sim.camera.convert_camera_pose`.

Known traps handled here:

- one pyrender ``OffscreenRenderer`` per process (:func:`offscreen_renderer`): two renderers break
  each other when one of them is garbage collected;
- MuJoCo stores mesh vertices in the geom frame (re-centred and re-oriented by the compiler), so a
  mesh is placed with ``geom_xpos``/``geom_xmat``, never with the body pose;
- ``mat_texid`` is indexed ``[material, role]``; the colour texture is role ``mjTEXROLE_RGB``
  (``mjTEXROLE_RGBA`` as fallback);
- MuJoCo flips the OBJ ``v`` texture coordinate and stores texture rows top first; pyrender
  flips its texture source on upload, so the texture coordinate given to pyrender is ``1 - v``;
- pyrender's ``IntrinsicsCamera`` measures the principal point from the image corner at pixel
  edges, OpenCV at pixel centres: ``cx_pyrender = cx_opencv + 0.5`` (same for ``cy``);
- depth and labels come from one flat-colour (segmentation) pass, which pyrender renders without
  multisampling, so every pixel holds the surface at its centre (the anti-aliased colour pass
  resolves depth from sub-pixel samples);
- the colour pass shades with ``sim/shaders/mesh_lambert.frag`` (:class:`LambertShaderCache`):
  the diffuse term of pyrender's own metallic-roughness BRDF, without its specular lobe. On the
  CPU rasteriser this project renders with (Mesa llvmpipe: no GPU) the specular microfacet terms
  per light were most of a frame: 0.39 -> 0.23 s of CPU per 640x480 frame with three point
  lights (pliers, 4x multisampling); the images lose the soft highlights of roughness 0.7;
- on llvmpipe a light loop bounded by a uniform reads every uniform by a per-lane gather: the
  loops get the scene's light counts as compile-time bounds (:class:`LambertShaderCache`), and
  nodes wholly outside the view frustum are not drawn (:meth:`MjRenderer._cull`; the arm's
  finely tessellated links are behind the wrist camera): pliers 0.18 -> 0.09 s of CPU per colour
  frame, every pixel the same (tests/test_render.py compares).
"""

from __future__ import annotations

import atexit
import logging
from dataclasses import dataclass

import numpy as np

import sim  # noqa: F401  (selects the EGL platform before any OpenGL import)
from sim.camera import convert_camera_pose

if not hasattr(np, "infty"):  # pyrender 0.1.45 still uses the alias removed in numpy 2
    setattr(np, "infty", np.inf)  # noqa: B010  (spelled so numpy's linter leaves it alone)

from pathlib import Path  # noqa: E402

import mujoco  # noqa: E402
import pyrender  # noqa: E402
import trimesh  # noqa: E402
from OpenGL.GL import (  # noqa: E402
    GL_COLOR_BUFFER_BIT,
    GL_DRAW_FRAMEBUFFER,
    GL_LINEAR,
    GL_READ_FRAMEBUFFER,
    GL_RGB,
    GL_UNSIGNED_BYTE,
    glBindFramebuffer,
    glBlitFramebuffer,
    glReadPixels,
)
from pyrender.shader_program import ShaderProgramCache  # noqa: E402

log = logging.getLogger(__name__)

#: Label of pixels that show no geom at all.
LABEL_BACKGROUND = -1

#: Label codes are stored in a 24-bit flat colour as ``label + _LABEL_OFFSET``; colour 0 (the
#: cleared buffer) is the background, so labels must lie in (-_LABEL_OFFSET, _LABEL_OFFSET).
_LABEL_OFFSET = 1 << 23

#: Near/far clipping distances (m). With a 24-bit depth buffer the depth resolution at distance
#: d is about d**2 / (znear * 2**24): 0.4 um at 1 m with znear = 0.15, far below the 1 mm
#: back-projection tolerance; the wrist camera never sees anything closer than 15 cm.
ZNEAR = 0.15
ZFAR = 30.0

#: Tessellation of curved primitives. Sag (distance between the true surface and the facets):
#: icosphere level 5 has edges of about 1.9 deg -> sag r * 1.4e-4 (14 um at r = 0.1 m);
#: 128 sections on a cylinder -> sag r * 3e-4. Both are well under the 1 mm depth tolerance.
SPHERE_SUBDIVISIONS = 5
CYLINDER_SECTIONS = 128

#: Half size (m) of the quad that stands in for an infinite plane (MuJoCo plane size 0).
INFINITE_PLANE_HALF_SIZE = 20.0

#: MuJoCo's default geom colour: a geom with this rgba and a material takes the material's rgba.
_DEFAULT_GEOM_RGBA = np.array([0.5, 0.5, 0.5, 1.0])

#: pyrender's PBR shader divides the diffuse term by pi; MuJoCo's Phong model does not. Light
#: intensities are scaled by this factor so that a MuJoCo light of diffuse d lights a surface
#: facing it about as brightly as MuJoCo would.
_PBR_DIFFUSE_GAIN = np.pi

#: The colour pass's fragment shader (see the module docstring).
LAMBERT_SHADER = Path(__file__).resolve().parent / "shaders" / "mesh_lambert.frag"


class LambertShaderCache(ShaderProgramCache):
    """pyrender's shader cache with the mesh fragment shader replaced by
    :data:`LAMBERT_SHADER` (every other shader is pyrender's own).

    :attr:`light_counts` (set by :class:`_Renderer` from the scene it renders) is compiled into
    the colour shader as the bounds of its light loops (``N_DIRECTIONAL_LIGHTS`` ...): llvmpipe
    runs a loop bounded by a uniform with every uniform read indexed per lane; a constant bound is
    unrolled into direct reads, the same arithmetic in the same order (bit-identical images),
    0.16 -> 0.11 s of CPU per 640x480 frame (pliers, four directional lights).
    """

    #: (directional, spot, point) lights of the scene being rendered, or None
    light_counts: tuple[int, int, int] | None = None

    def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
        if fragment_shader == "mesh.frag":
            fragment_shader = str(LAMBERT_SHADER)
            if self.light_counts is not None:
                # the counts pyrender's _bind_lighting sets: at most MAX_*_LIGHTS of each kind
                defines = dict(defines or {})
                for n, kind in zip(self.light_counts, ("DIRECTIONAL", "SPOT", "POINT"),
                                   strict=True):
                    defines[f"N_{kind}_LIGHTS"] = min(int(n), int(defines[f"MAX_{kind}_LIGHTS"]))
        return super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)


#: A render flag of :class:`_Renderer` beyond pyrender's own (which end at 1 << 13): read back
#: the colour only (the colour pass's depth is not used: depth comes from the flat pass).
COLOUR_ONLY = 1 << 20


class _Renderer(pyrender.renderer.Renderer):
    """pyrender's renderer (0.1.45) with the work nobody reads left out; every pixel is as
    pyrender renders it.

    - :data:`COLOUR_ONLY`: the colour pass resolves and reads back the colour buffer alone
      (pyrender also resolves the multisampled depth, reads it back and linearises it);
    - the light counts of the scene go to the shader cache (:class:`LambertShaderCache`).

    Not done, measured: drawing the flat (segmentation) pass into the single-sample framebuffer
    instead of the multisampled one with multisampling off saves the 4x clear and the resolve
    (about 8 of 19 ms of CPU per frame) but moves the depth of about 1 pixel in 300 by one unit
    of the ground-truth depth PNG (0.1 mm): llvmpipe evaluates depth at the samples' positions
    even with multisampling off, and the resolve keeps one sample. The ground truth stays as it
    was.
    """

    #: compile the scene's light counts into the colour shader (False: pyrender's uniform-bound
    #: loops; the tests compare the two)
    constant_light_loops = True

    def render(self, scene, flags, seg_node_map=None):
        if isinstance(self._program_cache, LambertShaderCache):
            self._program_cache.light_counts = (
                (len(scene.directional_light_nodes), len(scene.spot_light_nodes),
                 len(scene.point_light_nodes)) if self.constant_light_loops else None)
        return super().render(scene, flags, seg_node_map)

    def _read_main_framebuffer(self, scene, flags):
        if not flags & COLOUR_ONLY or flags & (pyrender.RenderFlags.DEPTH_ONLY
                                               | pyrender.RenderFlags.SEG
                                               | pyrender.RenderFlags.RGBA):
            return super()._read_main_framebuffer(scene, flags)
        # pyrender's colour resolve and read-back, without the depth
        width, height = self._main_fb_dims
        glBindFramebuffer(GL_READ_FRAMEBUFFER, self._main_fb_ms)
        glBindFramebuffer(GL_DRAW_FRAMEBUFFER, self._main_fb)
        glBlitFramebuffer(0, 0, width, height, 0, 0, width, height, GL_COLOR_BUFFER_BIT,
                          GL_LINEAR)
        glBindFramebuffer(GL_READ_FRAMEBUFFER, self._main_fb)
        color_buf = glReadPixels(0, 0, width, height, GL_RGB, GL_UNSIGNED_BYTE)
        color_im = np.flip(np.frombuffer(color_buf, dtype=np.uint8).reshape((height, width, 3)),
                           axis=0)
        return color_im, None


_RENDERER: pyrender.OffscreenRenderer | None = None


def _release_renderer() -> None:
    """Free the renderer's OpenGL context before the interpreter tears modules down."""
    global _RENDERER
    if _RENDERER is not None:
        try:
            _RENDERER.delete()
        except Exception:  # noqa: BLE001  (best effort at interpreter exit)
            pass
        _RENDERER = None


atexit.register(_release_renderer)


def offscreen_renderer(width: int, height: int) -> pyrender.OffscreenRenderer:
    """The one offscreen renderer of this process, resized to ``width`` x ``height``.

    pyrender renderers share process-wide OpenGL state; creating a second one and letting either
    be garbage collected breaks the other, so every render in the harness goes through this one.
    """
    global _RENDERER
    width, height = int(width), int(height)
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    if _RENDERER is None:
        _RENDERER = pyrender.OffscreenRenderer(viewport_width=width, viewport_height=height)
        # pyrender's renderer holds no OpenGL object before its first render: swap in ours
        _RENDERER._renderer = _Renderer(width, height)
        _RENDERER._renderer._program_cache = LambertShaderCache()
    else:
        _RENDERER.viewport_width = width
        _RENDERER.viewport_height = height
    return _RENDERER


class _OrderedScene(pyrender.Scene):
    """A pyrender scene that hands its mesh and light nodes out in name order.

    pyrender keeps nodes in sets, whose order changes between runs: lights were then summed in
    the shader in a different order (1 grey level off on a few pixels) and geoms at the same
    distance drawn in a different order. Sorted by name, identical inputs give identical images.
    """

    @property
    def mesh_nodes(self):
        return sorted(super().mesh_nodes, key=lambda n: n.name or "")

    @property
    def light_nodes(self):
        return sorted(super().light_nodes, key=lambda n: n.name or "")


@dataclass
class RenderOutput:
    """One rendered view.

    Attributes
    ----------
    color : (h, w, 3) uint8
        RGB image.
    depth : (h, w) float32 or None
        Metric depth along the optical axis (z of the OpenCV camera frame), 0 where no surface.
    labels : (h, w) int32 or None
        Per-pixel label of the geom seen there (see ``geom_labels`` of :class:`MjRenderer`),
        ``LABEL_BACKGROUND`` where no surface.
    """

    color: np.ndarray
    depth: np.ndarray | None = None
    labels: np.ndarray | None = None


def _check_K(K: np.ndarray) -> np.ndarray:
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3):
        raise ValueError(f"expected intrinsics K of shape (3, 3), got {K.shape}")
    if K[0, 1] != 0.0 or np.any(K[2] != [0.0, 0.0, 1.0]) or K[1, 0] != 0.0:
        raise ValueError(f"expected a pinhole K without skew ([[fx,0,cx],[0,fy,cy],[0,0,1]]), "
                         f"got {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
    return K


def _pose(xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(xmat).reshape(3, 3)
    T[:3, 3] = xpos
    return T


def _texture_image(model: mujoco.MjModel, tex_id: int) -> np.ndarray:
    """The RGB image of a 2d texture, rows top first, (h, w, 3) uint8."""
    w, h, c = (int(model.tex_width[tex_id]), int(model.tex_height[tex_id]),
               int(model.tex_nchannel[tex_id]))
    adr = int(model.tex_adr[tex_id])
    img = np.asarray(model.tex_data[adr:adr + w * h * c], dtype=np.uint8).reshape(h, w, c)
    if c == 1:
        img = np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img[:, :, :3])


def _material_texture(model: mujoco.MjModel, mat_id: int) -> int:
    """Texture id of a material's colour texture, or -1."""
    if mat_id < 0:
        return -1
    for role in (mujoco.mjtTextureRole.mjTEXROLE_RGB, mujoco.mjtTextureRole.mjTEXROLE_RGBA):
        tex = int(model.mat_texid[mat_id, int(role)])
        if tex >= 0:
            return tex
    return -1


def _geom_rgba(model: mujoco.MjModel, geom_id: int) -> np.ndarray:
    rgba = np.array(model.geom_rgba[geom_id], dtype=float)
    mat = int(model.geom_matid[geom_id])
    if mat >= 0 and np.allclose(rgba, _DEFAULT_GEOM_RGBA):
        rgba = np.array(model.mat_rgba[mat], dtype=float)
    return rgba


def _mesh_arrays(model: mujoco.MjModel, mesh_id: int):
    """Corner-split arrays of a MuJoCo mesh in its geom frame.

    Returns positions (n, 3), normals (n, 3), texcoords (n, 2) or None (MuJoCo ``v``), faces (f, 3).
    """
    vadr, vnum = int(model.mesh_vertadr[mesh_id]), int(model.mesh_vertnum[mesh_id])
    fadr, fnum = int(model.mesh_faceadr[mesh_id]), int(model.mesh_facenum[mesh_id])
    nadr, nnum = int(model.mesh_normaladr[mesh_id]), int(model.mesh_normalnum[mesh_id])
    verts = np.asarray(model.mesh_vert[vadr:vadr + vnum], dtype=float)
    faces = np.asarray(model.mesh_face[fadr:fadr + fnum], dtype=np.int64)
    normals_all = np.asarray(model.mesh_normal[nadr:nadr + nnum], dtype=float)
    face_normals = np.asarray(model.mesh_facenormal[fadr:fadr + fnum], dtype=np.int64)
    tadr, tnum = int(model.mesh_texcoordadr[mesh_id]), int(model.mesh_texcoordnum[mesh_id])
    if tadr >= 0 and tnum > 0:
        uv_all = np.asarray(model.mesh_texcoord[tadr:tadr + tnum], dtype=float)
        face_uv = np.asarray(model.mesh_facetexcoord[fadr:fadr + fnum], dtype=np.int64)
    else:
        uv_all, face_uv = None, np.zeros_like(faces)
    # A vertex of the rendered mesh is one (position, normal, texcoord) triple; share equal ones.
    keys = np.stack([faces.ravel(), face_normals.ravel(), face_uv.ravel()], axis=1)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    positions = verts[uniq[:, 0]]
    normals = normals_all[uniq[:, 1]] if nnum > 0 else None
    uv = uv_all[uniq[:, 2]] if uv_all is not None else None
    return positions, normals, uv, inverse.reshape(-1, 3)


class MjRenderer:
    """Renders a compiled MuJoCo model with pyrender.

    Parameters
    ----------
    model : mujoco.MjModel
        The compiled model. Its meshes, materials and textures are converted once.
    geom_labels : (ngeom,) int, optional
        Label of each geom in the label image (default: the geom's body id). Values must lie in
        (-2**23, 2**23); ``LABEL_BACKGROUND`` marks pixels without any geom.
    visible_groups : iterable of int
        Geom groups to render. Group 3 is MuJoCo's usual collision-only group and is hidden by
        default, like in MuJoCo's viewer. Geoms with alpha 0 are never rendered.
    bg_color : (3,) float
        Background colour in [0, 1].
    """

    #: hide the nodes outside the view frustum before drawing (:meth:`_cull`; False: draw all,
    #: as the tests do to compare)
    cull_offscreen = True

    def __init__(self, model: mujoco.MjModel, *, geom_labels=None, visible_groups=(0, 1, 2),
                 bg_color=(0.0, 0.0, 0.0)):
        self.model = model
        if geom_labels is None:
            geom_labels = np.asarray(model.geom_bodyid, dtype=np.int64)
        geom_labels = np.asarray(geom_labels, dtype=np.int64)
        if geom_labels.shape != (model.ngeom,):
            raise ValueError(f"expected geom_labels of shape ({model.ngeom},), "
                             f"got {geom_labels.shape}")
        if np.any(np.abs(geom_labels) >= _LABEL_OFFSET):
            raise ValueError(f"geom labels must lie in (-{_LABEL_OFFSET}, {_LABEL_OFFSET})")
        self.geom_labels = geom_labels
        self.visible_groups = frozenset(int(g) for g in visible_groups)
        self.scene = _OrderedScene(bg_color=np.r_[np.asarray(bg_color, float), 1.0],
                                    ambient_light=self._ambient())
        self._textures: dict[int, pyrender.Texture] = {}
        self._texture_warned: set[int] = set()
        self.geom_nodes: dict[int, pyrender.Node] = {}
        self._seg_map: dict[pyrender.Node, np.ndarray] = {}
        #: bounding sphere (centre, radius) of each geom's mesh in its geom frame (culling)
        self._bounds: dict[int, tuple[np.ndarray, float]] = {}
        for g in range(model.ngeom):
            if int(model.geom_group[g]) not in self.visible_groups:
                continue
            rgba = _geom_rgba(model, g)
            if rgba[3] <= 0.0:
                continue
            mesh = self._geom_mesh(g, rgba)
            node = pyrender.Node(name=f"geom{g}", mesh=mesh, matrix=np.eye(4))
            self.scene.add_node(node)
            self.geom_nodes[g] = node
            pts = np.concatenate([np.asarray(p.positions, dtype=float) for p in mesh.primitives])
            mid = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
            self._bounds[g] = (mid, float(np.sqrt(np.max(np.sum((pts - mid) ** 2, axis=1)))))
            code = int(geom_labels[g]) + _LABEL_OFFSET
            self._seg_map[node] = np.array([(code >> 16) & 255, (code >> 8) & 255, code & 255])
        self._light_nodes = self._add_lights()
        self._camera = pyrender.IntrinsicsCamera(1.0, 1.0, 0.5, 0.5, znear=ZNEAR, zfar=ZFAR)
        self._camera_node = self.scene.add(self._camera, pose=np.eye(4))
        self._headlight_node = None
        if int(model.vis.headlight.active):
            diffuse = np.asarray(model.vis.headlight.diffuse, dtype=float)
            if diffuse.max() > 0:
                light = pyrender.DirectionalLight(color=diffuse / diffuse.max(),
                                                  intensity=_PBR_DIFFUSE_GAIN * diffuse.max())
                self._headlight_node = self.scene.add(light, name="headlight", pose=np.eye(4))
        log.debug("pyrender scene: %d geoms, %d lights", len(self.geom_nodes),
                  len(self._light_nodes))

    # ----------------------------------------------------------------------------- building
    def _ambient(self) -> np.ndarray:
        m = self.model
        amb = np.zeros(3)
        if int(m.vis.headlight.active):
            amb += np.asarray(m.vis.headlight.ambient, dtype=float)
        for i in range(m.nlight):
            if int(m.light_active[i]):
                amb += np.asarray(m.light_ambient[i], dtype=float)
        return np.clip(amb, 0.0, 1.0)

    def _texture(self, tex_id: int) -> pyrender.Texture:
        if tex_id not in self._textures:
            img = _texture_image(self.model, tex_id)
            sampler = pyrender.Sampler(magFilter=pyrender.constants.GLTF.LINEAR,
                                       minFilter=pyrender.constants.GLTF.LINEAR_MIPMAP_LINEAR,
                                       wrapS=pyrender.constants.GLTF.REPEAT,
                                       wrapT=pyrender.constants.GLTF.REPEAT)
            self._textures[tex_id] = pyrender.Texture(source=img, source_channels="RGB",
                                                      sampler=sampler)
        return self._textures[tex_id]

    def _material(self, rgba: np.ndarray, texture: pyrender.Texture | None, double_sided: bool):
        return pyrender.MetallicRoughnessMaterial(
            baseColorFactor=rgba, baseColorTexture=texture, metallicFactor=0.0,
            roughnessFactor=0.7, doubleSided=double_sided,
            alphaMode="BLEND" if rgba[3] < 1.0 else "OPAQUE")

    def _geom_mesh(self, g: int, rgba: np.ndarray) -> pyrender.Mesh:
        m = self.model
        gtype = int(m.geom_type[g])
        size = np.asarray(m.geom_size[g], dtype=float)
        mat_id = int(m.geom_matid[g])
        tex_id = _material_texture(m, mat_id)
        if tex_id >= 0 and int(m.tex_type[tex_id]) != int(mujoco.mjtTexture.mjTEXTURE_2D):
            tex_id = self._flatten_texture(g, tex_id, "a cube or skybox texture", rgba)
            rgba = self._flat_rgba
        T = mujoco.mjtGeom
        if gtype == T.mjGEOM_MESH:
            pos, nrm, uv, faces = _mesh_arrays(m, int(m.geom_dataid[g]))
            texture = None
            if tex_id >= 0 and uv is not None:
                texture = self._texture(tex_id)
                uv = np.c_[uv[:, 0], 1.0 - uv[:, 1]]
            elif tex_id >= 0:
                self._flatten_texture(g, tex_id, "a mesh without texture coordinates", rgba)
                rgba = self._flat_rgba
            prim = pyrender.Primitive(positions=pos, normals=nrm,
                                      texcoord_0=uv if texture else None, indices=faces,
                                      material=self._material(rgba, texture, True))
            return pyrender.Mesh([prim])
        if gtype == T.mjGEOM_PLANE:
            return self._plane_mesh(g, size, rgba, tex_id)
        if tex_id >= 0:
            self._flatten_texture(g, tex_id, "a 2d texture on a primitive other than a plane", rgba)
            rgba = self._flat_rgba
        if gtype == T.mjGEOM_BOX:
            tm, smooth = trimesh.creation.box(extents=2.0 * size[:3]), False
        elif gtype == T.mjGEOM_SPHERE:
            tm, smooth = trimesh.creation.icosphere(SPHERE_SUBDIVISIONS, radius=size[0]), True
        elif gtype == T.mjGEOM_ELLIPSOID:
            tm = trimesh.creation.icosphere(SPHERE_SUBDIVISIONS, radius=1.0)
            tm.apply_scale(size[:3])
            smooth = True
        elif gtype == T.mjGEOM_CAPSULE:
            tm = trimesh.creation.capsule(height=2.0 * size[1], radius=size[0],
                                          count=[CYLINDER_SECTIONS, CYLINDER_SECTIONS // 2])
            smooth = True
        elif gtype == T.mjGEOM_CYLINDER:
            tm = trimesh.creation.cylinder(radius=size[0], height=2.0 * size[1],
                                           sections=CYLINDER_SECTIONS)
            smooth = False
        else:
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}"
            raise NotImplementedError(
                f"geom {name!r} has type {mujoco.mjtGeom(gtype).name}, which the renderer does "
                "not draw (plane, box, sphere, capsule, cylinder, ellipsoid and mesh are "
                "supported); put it in group 3 to hide it or use a mesh")
        mat = self._material(rgba, None, False)
        return pyrender.Mesh.from_trimesh(tm, material=mat, smooth=smooth)

    def _flatten_texture(self, g: int, tex_id: int, why: str, rgba: np.ndarray) -> int:
        """Replace a texture the renderer cannot map by its mean colour (logged once)."""
        mean = _texture_image(self.model, tex_id).reshape(-1, 3).mean(axis=0) / 255.0
        self._flat_rgba = np.r_[rgba[:3] * mean, rgba[3]]
        if tex_id not in self._texture_warned:
            self._texture_warned.add(tex_id)
            name = mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}"
            log.warning("geom %r: %s is drawn in the texture's mean colour", name, why)
        return -1

    def _plane_mesh(self, g: int, size: np.ndarray, rgba: np.ndarray, tex_id: int):
        m = self.model
        hx = size[0] if size[0] > 0 else INFINITE_PLANE_HALF_SIZE
        hy = size[1] if size[1] > 0 else INFINITE_PLANE_HALF_SIZE
        pos = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]])
        faces = np.array([[0, 1, 2], [0, 2, 3]])
        nrm = np.tile([0.0, 0.0, 1.0], (4, 1))
        texture, uv = None, None
        if tex_id >= 0:
            mat_id = int(m.geom_matid[g])
            rep = np.asarray(m.mat_texrepeat[mat_id], dtype=float)
            if bool(m.mat_texuniform[mat_id]):
                # texrepeat repetitions per unit length
                uv = pos[:, :2] * rep
            else:
                # texrepeat repetitions over the whole plane
                uv = (pos[:, :2] + [hx, hy]) / [2 * hx, 2 * hy] * rep
            texture = self._texture(tex_id)
            uv = np.c_[uv[:, 0], 1.0 - uv[:, 1]]
        prim = pyrender.Primitive(positions=pos, normals=nrm, texcoord_0=uv, indices=faces,
                                  material=self._material(rgba, texture, False))
        return pyrender.Mesh([prim])

    def _add_lights(self) -> list[tuple[int, pyrender.Node]]:
        m = self.model
        nodes = []
        centre = np.asarray(m.stat.center, dtype=float)
        for i in range(m.nlight):
            if not int(m.light_active[i]):
                continue
            diffuse = np.asarray(m.light_diffuse[i], dtype=float)
            peak = float(diffuse.max())
            if peak <= 0:
                continue
            colour = diffuse / peak
            ltype = int(m.light_type[i])
            if ltype == int(mujoco.mjtLightType.mjLIGHT_DIRECTIONAL):
                light = pyrender.DirectionalLight(color=colour,
                                                  intensity=_PBR_DIFFUSE_GAIN * peak)
            else:
                # pyrender's point and spot lights fall off with 1/d**2; MuJoCo's (attenuation
                # 1 0 0 by default) do not. Scale so the model's centre gets MuJoCo's brightness.
                d2 = float(np.sum((np.asarray(m.light_pos0[i]) - centre) ** 2))
                intensity = _PBR_DIFFUSE_GAIN * peak * max(d2, 1e-6)
                if ltype == int(mujoco.mjtLightType.mjLIGHT_SPOT):
                    cutoff = np.deg2rad(float(m.light_cutoff[i]))
                    light = pyrender.SpotLight(color=colour, intensity=intensity,
                                               innerConeAngle=0.5 * cutoff,
                                               outerConeAngle=cutoff)
                else:
                    light = pyrender.PointLight(color=colour, intensity=intensity)
            nodes.append((i, self.scene.add(light, name=f"light{i}", pose=np.eye(4))))
        return nodes

    # ----------------------------------------------------------------------------- per frame
    def update(self, data: mujoco.MjData) -> None:
        """Move every node to the geom and light poses of ``data`` (after ``mj_forward``)."""
        for g, node in self.geom_nodes.items():
            self.scene.set_pose(node, _pose(data.geom_xpos[g], data.geom_xmat[g]))
        for i, node in self._light_nodes:
            # pyrender lights shine along their node's -z axis
            z = -np.asarray(data.light_xdir[i], dtype=float)
            z /= np.linalg.norm(z)
            x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
            x /= np.linalg.norm(x)
            T = np.eye(4)
            T[:3, :3] = np.c_[x, np.cross(z, x), z]
            T[:3, 3] = data.light_xpos[i]
            self.scene.set_pose(node, T)

    def _cull(self, K: np.ndarray, T_world_camera: np.ndarray, width: int, height: int) -> None:
        """Hide the nodes whose bounding sphere lies wholly outside the view frustum.

        A hidden node is one pyrender would have drawn with every triangle clipped away: the
        images are the same, without the vertex work (the arm's finely tessellated links, behind
        the wrist camera, were most of the draw calls' cost). The frustum is taken a pixel wider
        than the image on every side.
        """
        T_cam_world = np.linalg.inv(T_world_camera)
        nodes = list(self._bounds)
        centres = np.array([self._bounds[g][0] for g in nodes])
        radii = np.array([self._bounds[g][1] for g in nodes]) * (1.0 + 1e-6) + 1e-9
        poses = np.array([self.scene.get_pose(self.geom_nodes[g]) for g in nodes])
        world = np.einsum("nij,nj->ni", poses[:, :3, :3], centres) + poses[:, :3, 3]
        p = world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        inside = (z + radii >= ZNEAR) & (z - radii <= ZFAR)
        # pixel edges at -0.5 and size - 0.5 in OpenCV pixel coordinates, widened by 1 px
        for coord, f, c, size in ((x, K[0, 0], K[0, 2], width), (y, K[1, 1], K[1, 2], height)):
            lo, hi = (-1.5 - c) / f, (size + 0.5 - c) / f
            inside &= (coord - lo * z) / np.sqrt(1.0 + lo * lo) >= -radii
            inside &= (hi * z - coord) / np.sqrt(1.0 + hi * hi) >= -radii
        for g, vis in zip(nodes, inside, strict=True):
            self.geom_nodes[g].mesh.is_visible = bool(vis)

    def render(self, data: mujoco.MjData | None, K: np.ndarray, T_world_camera: np.ndarray,
               width: int, height: int, *, depth: bool = False,
               labels: bool = False) -> RenderOutput:
        """Render one view.

        Parameters
        ----------
        data : mujoco.MjData or None
            State to render (after ``mj_forward``); None keeps the poses of the last update.
        K : (3, 3) float
            OpenCV intrinsics (pixel centres at integer coordinates).
        T_world_camera : (4, 4) float
            Camera pose, OpenCV convention (x right, y down, z forward).
        width, height : int
            Image size in pixels.
        depth, labels : bool
            Also render metric depth / the label image (scoring only).

        Returns
        -------
        RenderOutput
        """
        K = _check_K(K)
        T = np.asarray(T_world_camera, dtype=float)
        if T.shape != (4, 4):
            raise ValueError(f"expected T_world_camera of shape (4, 4), got {T.shape}")
        if data is not None:
            self.update(data)
        cam = self._camera
        cam.fx, cam.fy = K[0, 0], K[1, 1]
        cam.cx, cam.cy = K[0, 2] + 0.5, K[1, 2] + 0.5
        T_gl = convert_camera_pose(T)
        self.scene.set_pose(self._camera_node, T_gl)
        if self._headlight_node is not None:
            self.scene.set_pose(self._headlight_node, T_gl)
        if self.cull_offscreen:
            self._cull(K, T, width, height)
        else:
            for node in self.geom_nodes.values():
                node.mesh.is_visible = True
        r = offscreen_renderer(width, height)
        color, _ = r.render(self.scene, flags=COLOUR_ONLY)
        out = RenderOutput(color=np.ascontiguousarray(color[:, :, :3]))
        if depth or labels:
            seg, z = r.render(self.scene, flags=pyrender.RenderFlags.SEG,
                              seg_node_map=self._seg_map)
            if depth:
                out.depth = np.ascontiguousarray(z, dtype=np.float32)
            if labels:
                code = ((seg[:, :, 0].astype(np.int64) << 16) | (seg[:, :, 1].astype(np.int64) << 8)
                        | seg[:, :, 2].astype(np.int64))
                lab = (code - _LABEL_OFFSET).astype(np.int32)
                lab[code == 0] = LABEL_BACKGROUND
                out.labels = lab
        return out


def backproject(depth: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray,
                mask: np.ndarray | None = None) -> np.ndarray:
    """World points of the pixels of a depth image.

    Parameters
    ----------
    depth : (h, w) float
        Depth along the optical axis (OpenCV z), 0 where no surface.
    K : (3, 3) float
    T_world_camera : (4, 4) float, OpenCV convention.
    mask : (h, w) bool, optional
        Pixels to use (default: all with depth > 0).

    Returns
    -------
    points : (n, 3) float
        In row-major pixel order.
    """
    depth = np.asarray(depth, dtype=float)
    if depth.ndim != 2:
        raise ValueError(f"expected a (h, w) depth image, got shape {depth.shape}")
    K = _check_K(K)
    sel = depth > 0 if mask is None else (np.asarray(mask, bool) & (depth > 0))
    v, u = np.nonzero(sel)
    z = depth[v, u]
    p_cam = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
    T = np.asarray(T_world_camera, dtype=float)
    return p_cam @ T[:3, :3].T + T[:3, 3]
