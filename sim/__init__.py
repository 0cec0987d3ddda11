"""Simulation harness for artrecon: MuJoCo scenes, the arm, eye-in-hand capture, scoring.

Rendering is offscreen on every machine (no display, no GPU needed): the EGL platform is chosen
here, before any OpenGL import, so users never have to set it.
"""

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("MUJOCO_GL", "egl")
