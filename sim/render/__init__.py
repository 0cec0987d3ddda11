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


import numpy as np

import sim  # noqa: F401  (selects the EGL platform before any OpenGL import)

if not hasattr(np, "infty"):  # pyrender 0.1.45 still uses the alias removed in numpy 2
    setattr(np, "infty", np.inf)  # noqa: B010  (spelled so numpy's linter leaves it alone)

from sim.render.context import (  # noqa: E402  (pyrender after the two lines above)
    COLOUR_ONLY,
    LAMBERT_SHADER,
    LambertShaderCache,
    offscreen_renderer,
)
from sim.render.materials import material_texture, texture_image  # noqa: E402
from sim.render.output import (  # noqa: E402
    LABEL_BACKGROUND,
    ZFAR,
    ZNEAR,
    RenderOutput,
    backproject,
)
from sim.render.renderer import MjRenderer  # noqa: E402

__all__ = [
    "COLOUR_ONLY", "LABEL_BACKGROUND", "LAMBERT_SHADER", "ZFAR", "ZNEAR", "LambertShaderCache",
    "MjRenderer", "RenderOutput", "backproject", "material_texture", "offscreen_renderer",
    "texture_image",
]
