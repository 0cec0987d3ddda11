"""A MuJoCo model's looks as arrays: its textures' images, materials' colours and meshes (corner
split, in the geom frame), and how finely curved primitives are tessellated."""

from __future__ import annotations

import mujoco
import numpy as np

#: Tessellation of curved primitives. Sag (distance between the true surface and the facets):
#: icosphere level 5 has edges of about 1.9 deg -> sag r * 1.4e-4 (14 um at r = 0.1 m);
#: 128 sections on a cylinder -> sag r * 3e-4. Both are well under the 1 mm depth tolerance.
SPHERE_SUBDIVISIONS = 5
CYLINDER_SECTIONS = 128

#: Half size (m) of the quad that stands in for an infinite plane (MuJoCo plane size 0).
INFINITE_PLANE_HALF_SIZE = 20.0

#: MuJoCo's default geom colour: a geom with this rgba and a material takes the material's rgba.
DEFAULT_GEOM_RGBA = np.array([0.5, 0.5, 0.5, 1.0])

#: pyrender's PBR shader divides the diffuse term by pi; MuJoCo's Phong model does not. Light
#: intensities are scaled by this factor so that a MuJoCo light of diffuse d lights a surface
#: facing it about as brightly as MuJoCo would.
PBR_DIFFUSE_GAIN = np.pi


def texture_image(model: mujoco.MjModel, tex_id: int) -> np.ndarray:
    """The RGB image of a 2d texture, rows top first, (h, w, 3) uint8."""
    w, h, c = (int(model.tex_width[tex_id]), int(model.tex_height[tex_id]),
               int(model.tex_nchannel[tex_id]))
    adr = int(model.tex_adr[tex_id])
    img = np.asarray(model.tex_data[adr:adr + w * h * c], dtype=np.uint8).reshape(h, w, c)
    if c == 1:
        img = np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img[:, :, :3])


def material_texture(model: mujoco.MjModel, mat_id: int) -> int:
    """Texture id of a material's colour texture, or -1."""
    if mat_id < 0:
        return -1
    for role in (mujoco.mjtTextureRole.mjTEXROLE_RGB, mujoco.mjtTextureRole.mjTEXROLE_RGBA):
        tex = int(model.mat_texid[mat_id, int(role)])
        if tex >= 0:
            return tex
    return -1


def geom_rgba(model: mujoco.MjModel, geom_id: int) -> np.ndarray:
    rgba = np.array(model.geom_rgba[geom_id], dtype=float)
    mat = int(model.geom_matid[geom_id])
    if mat >= 0 and np.allclose(rgba, DEFAULT_GEOM_RGBA):
        rgba = np.array(model.mat_rgba[mat], dtype=float)
    return rgba


def mesh_arrays(model: mujoco.MjModel, mesh_id: int):
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
