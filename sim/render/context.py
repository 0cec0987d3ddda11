"""The OpenGL side: the one offscreen renderer of the process, pyrender's renderer with the work
nobody reads left out, and the colour pass's shader (see :mod:`sim.render`)."""

from __future__ import annotations

import atexit
import ctypes
from pathlib import Path

import numpy as np
import pyrender
from OpenGL.GL import (
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
from pyrender.shader_program import ShaderProgramCache

#: The colour pass's fragment shader (see :mod:`sim.render`).
LAMBERT_SHADER = Path(__file__).resolve().parents[1] / "shaders" / "mesh_lambert.frag"


def interrupt_of(err: ctypes.ArgumentError) -> KeyboardInterrupt | None:
    """The Ctrl-C inside an OpenGL call's argument conversion, else None: PyOpenGL converts the
    arguments in Python (numpy to ctypes), and a SIGINT landing there reaches the caller as
    ``ctypes.ArgumentError('argument 3: KeyboardInterrupt: ...')``, which no interrupt handler
    would catch (the capture then ended in a traceback instead of its one line)."""
    return KeyboardInterrupt() if "KeyboardInterrupt" in str(err) else None


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
        try:
            return super().render(scene, flags, seg_node_map)
        except ctypes.ArgumentError as err:
            raise interrupt_of(err) or err from err

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
