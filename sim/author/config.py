"""The options of an import (``python -m sim.author import``): :class:`ImportConfig` and the
choices its fields take. Its own module so that the scene writer and the import both read it
without importing each other."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from sim.assets import OBJECT_TEXEL, SEED
from sim.author.source import rotation_about

#: Up axes the source may have (``--up``): the rotation taking it to +z.
UP_AXES = {"+z": np.eye(3), "-z": np.diag([1.0, -1.0, -1.0]),
           "+y": rotation_about([1.0, 0.0, 0.0], math.pi / 2),
           "-y": rotation_about([1.0, 0.0, 0.0], -math.pi / 2),
           "+x": rotation_about([0.0, 1.0, 0.0], -math.pi / 2),
           "-x": rotation_about([0.0, 1.0, 0.0], math.pi / 2)}


#: How the parts are textured (:attr:`ImportConfig.texture`).
TEXTURES = ("generated", "source")
#: Collision shapes of meshes (:attr:`ImportConfig.collision`).
COLLISIONS = ("box", "hull")


@dataclass(frozen=True)
class ImportConfig:
    """How an object is imported (the options of ``python -m sim.author import``)."""

    name: str | None = None
    """scene name: the file stem and the prefix of its assets (default: from the source file,
    its folder's name for a PartNet-Mobility ``mobility.urdf``)"""
    size: float = 0.25
    """largest extent (m) of the object at configuration A after scaling (the bundled objects
    are 16 - 32 cm: the capture rings and the table fit that)"""
    scale: float | None = None
    """a fixed scale factor instead of ``size`` (1: keep a metric source's size)"""
    up: str = "+z"
    """the source's up axis (``+z``, ``+y``, ...), turned to the world's +z"""
    body: str | None = None
    """MJCF only: the object's root body (default: the only top-level body with geoms)"""
    config_a: Mapping[str, float] = field(default_factory=dict)
    """joint values of configuration A (rad, or m after scaling); others at 0 or their limit"""
    config_b: Mapping[str, float] = field(default_factory=dict)
    """joint values of configuration B; others move by the default motion"""
    revolute_motion: float = math.radians(30.0)
    """default motion A -> B of a revolute joint (rad): the method sees 25 - 35 deg well"""
    prismatic_motion: float = 0.10
    """default motion A -> B of a prismatic joint (m): the method sees 8 - 12 cm well"""
    density: float = 500.0
    """density (kg/m^3) of the collision shapes, which carry the mass (a hollow toy or wooden
    furniture: the bundled objects use 400 - 600)"""
    texel: float = OBJECT_TEXEL
    """wanted texel size (m) of the generated textures"""
    seed: int = SEED
    """master seed of the textures (each part's seed derives from it and the part's name)"""
    collision: str = "box"
    """``box``: each collision mesh becomes the oriented box around it (the simple primitives
    the bundled scenes use; the arm's default grasp points lie on box and cylinder faces);
    ``hull``: its convex hull (closer to a round shape; no default grasp points on it)"""
    texture: str = "generated"
    """``generated``: every link's meshes UV-unwrapped and given a new non-repeating texture
    (what SfM needs); ``source``: keep each visual mesh's own UVs and texture image (a scanned
    or photo-textured model), refused for a mesh that has none"""
    arm: str = "puma560"
    """the arm on the stage: ``puma560`` or ``panda``"""
    overwrite: bool = False
    """replace files of an earlier import of the same name in the output folder"""

    def __post_init__(self):
        if self.up not in UP_AXES:
            raise ValueError(f"up must be one of {sorted(UP_AXES)}, got {self.up!r}")
        if not self.size > 0 or (self.scale is not None and not self.scale > 0):
            raise ValueError(f"size and scale must be positive, got {self.size}, {self.scale}")
        if not self.density > 0 or not self.texel > 0:
            raise ValueError("density and texel must be positive")
        if self.collision not in COLLISIONS:
            raise ValueError(f"collision must be one of {COLLISIONS}, got {self.collision!r}")
        if self.texture not in TEXTURES:
            raise ValueError(f"texture must be one of {TEXTURES}, got {self.texture!r}")
