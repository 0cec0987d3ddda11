"""Simulation harness for artrecon: MuJoCo scenes, the arm, eye-in-hand capture, scoring.

Rendering is offscreen on every machine (no display, no GPU needed): the EGL platform is chosen
here, before any OpenGL import, so users never have to set it.
"""

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
os.environ.setdefault("MUJOCO_GL", "egl")
# Mesa's llvmpipe rasterises with several threads, and its blending order then differs by one grey
# level between runs on a few pixels; one thread makes every render byte-identical (determinism).
os.environ.setdefault("LP_NUM_THREADS", "1")
