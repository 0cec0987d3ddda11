"""The renderer of a compiled MuJoCo model (:class:`MjRenderer`): its pyrender scene built once,
moved to each state and drawn through the wrist camera (see :mod:`sim.render` for the traps)."""

from __future__ import annotations

import logging

import mujoco
import numpy as np
import pyrender
import trimesh

from sim.camera import convert_camera_pose
from sim.render.context import COLOUR_ONLY, offscreen_renderer
from sim.render.materials import (
    CYLINDER_SECTIONS,
    INFINITE_PLANE_HALF_SIZE,
    PBR_DIFFUSE_GAIN,
    SPHERE_SUBDIVISIONS,
    geom_rgba,
    material_texture,
    mesh_arrays,
    texture_image,
)
from sim.render.output import LABEL_BACKGROUND, LABEL_OFFSET, ZFAR, ZNEAR, RenderOutput, check_K

log = logging.getLogger(__name__)


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


def _pose(xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(xmat).reshape(3, 3)
    T[:3, 3] = xpos
    return T


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
        if np.any(np.abs(geom_labels) >= LABEL_OFFSET):
            raise ValueError(f"geom labels must lie in (-{LABEL_OFFSET}, {LABEL_OFFSET})")
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
            rgba = geom_rgba(model, g)
            if rgba[3] <= 0.0:
                continue
            mesh = self._geom_mesh(g, rgba)
            node = pyrender.Node(name=f"geom{g}", mesh=mesh, matrix=np.eye(4))
            self.scene.add_node(node)
            self.geom_nodes[g] = node
            pts = np.concatenate([np.asarray(p.positions, dtype=float) for p in mesh.primitives])
            mid = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
            self._bounds[g] = (mid, float(np.sqrt(np.max(np.sum((pts - mid) ** 2, axis=1)))))
            code = int(geom_labels[g]) + LABEL_OFFSET
            self._seg_map[node] = np.array([(code >> 16) & 255, (code >> 8) & 255, code & 255])
        self._light_nodes = self._add_lights()
        self._camera = pyrender.IntrinsicsCamera(1.0, 1.0, 0.5, 0.5, znear=ZNEAR, zfar=ZFAR)
        self._camera_node = self.scene.add(self._camera, pose=np.eye(4))
        self._headlight_node = None
        if int(model.vis.headlight.active):
            diffuse = np.asarray(model.vis.headlight.diffuse, dtype=float)
            if diffuse.max() > 0:
                light = pyrender.DirectionalLight(color=diffuse / diffuse.max(),
                                                  intensity=PBR_DIFFUSE_GAIN * diffuse.max())
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
            img = texture_image(self.model, tex_id)
            # RGBA, not RGB: pyrender uploads the rows packed while OpenGL reads them padded to 4
            # bytes, so an RGB texture whose width * 3 is not a multiple of 4 was drawn sheared,
            # its last rows read from beyond the buffer (different in every renderer: chest's
            # 322-pixel-wide texture made its captures differ from run to run)
            img = np.concatenate([img, np.full(img.shape[:2] + (1,), 255, np.uint8)], axis=2)
            sampler = pyrender.Sampler(magFilter=pyrender.constants.GLTF.LINEAR,
                                       minFilter=pyrender.constants.GLTF.LINEAR_MIPMAP_LINEAR,
                                       wrapS=pyrender.constants.GLTF.REPEAT,
                                       wrapT=pyrender.constants.GLTF.REPEAT)
            self._textures[tex_id] = pyrender.Texture(source=img, source_channels="RGBA",
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
        tex_id = material_texture(m, mat_id)
        if tex_id >= 0 and int(m.tex_type[tex_id]) != int(mujoco.mjtTexture.mjTEXTURE_2D):
            tex_id = self._flatten_texture(g, tex_id, "a cube or skybox texture", rgba)
            rgba = self._flat_rgba
        T = mujoco.mjtGeom
        if gtype == T.mjGEOM_MESH:
            pos, nrm, uv, faces = mesh_arrays(m, int(m.geom_dataid[g]))
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
        mean = texture_image(self.model, tex_id).reshape(-1, 3).mean(axis=0) / 255.0
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
                                                  intensity=PBR_DIFFUSE_GAIN * peak)
            else:
                # pyrender's point and spot lights fall off with 1/d**2; MuJoCo's (attenuation
                # 1 0 0 by default) do not. Scale so the model's centre gets MuJoCo's brightness.
                d2 = float(np.sum((np.asarray(m.light_pos0[i]) - centre) ** 2))
                intensity = PBR_DIFFUSE_GAIN * peak * max(d2, 1e-6)
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
        K = check_K(K)
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
                lab = (code - LABEL_OFFSET).astype(np.int32)
                lab[code == 0] = LABEL_BACKGROUND
                out.labels = lab
        return out
