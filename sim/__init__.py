"""Simulation harness for artrecon: MuJoCo scenes, the arm, eye-in-hand capture, scoring.

Rendering is offscreen on every machine (no display, no GPU needed): the EGL platform is chosen
here, before any OpenGL import, so users never have to set it.
"""

import logging
import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("MUJOCO_GL", "egl")


def _egl_device_type() -> None:
    """Give PyOpenGL 3.1.0's EGL module the ``EGLDeviceEXT`` handle type.

    pyrender 0.1.45 pins PyOpenGL 3.1.0, whose EGL bindings predate EGL_EXT_device_base; with
    MUJOCO_GL=egl, ``import mujoco`` (4.x) loads its EGL backend, which needs that type, and fails
    with an AttributeError. PyOpenGL >= 3.1.1 defines it exactly so: an opaque pointer.
    OpenGL.GL's shader module is imported first: PyOpenGL 3.1.0 compares GL extension names
    (str) with EGL's prefix (bytes) once EGL is loaded, so importing pyrender after it fails.
    """
    try:
        # here, after PYOPENGL_PLATFORM is set, and tried: a machine without EGL still loads sim
        import OpenGL.GL.shaders  # noqa: F401 (before OpenGL.EGL, see above)
        from OpenGL import EGL  # after the platform is chosen above
        from OpenGL._opaque import opaque_pointer_cls  # after the platform is chosen above
        from OpenGL.raw.EGL import _types  # after the platform is chosen above
    except Exception:  # no EGL library here: rendering will say so when it is needed
        return
    if not hasattr(EGL, "EGLDeviceEXT"):
        _types.EGLDeviceEXT = EGL.EGLDeviceEXT = opaque_pointer_cls("EGLDeviceEXT")


if os.environ.get("MUJOCO_GL") == "egl":
    _egl_device_type()


def _mujoco_warnings_to_log() -> None:
    """Send MuJoCo's warnings (e.g. "XML contains a 'NaN'") to the ``mujoco`` logger. Without a
    handler MuJoCo prints them and appends them to MUJOCO_LOG.TXT in the working folder: a file
    no command should write where the user happens to stand."""
    import mujoco  # after the EGL setup above: mujoco loads its EGL backend on import

    log = logging.getLogger("mujoco")
    mujoco.set_mju_user_warning(lambda message: log.warning("MuJoCo: %s", message))


_mujoco_warnings_to_log()
