"""What the MJCF and URDF writers share: exact number formatting, the link meshes as STL files
beside the robot file, its header comment, and writing it all whole or not at all."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from artrecon.export.twin import Twin
from artrecon.files import write_files_atomic

__all__ = ["number", "numbers", "mesh_bytes", "mesh_files", "header", "write_robot"]


def number(x: float) -> str:
    """Shortest repr that round-trips a float64 (the twin is exact to the last bit)."""
    return repr(float(x))


def numbers(a) -> str:
    """Space-separated shortest round-trip floats of an array (any shape, row-major)."""
    return " ".join(number(x) for x in np.asarray(a, dtype=float).reshape(-1))


def mesh_bytes(mesh: trimesh.Trimesh) -> bytes:
    """Binary STL of a mesh."""
    return trimesh.exchange.stl.export_stl(mesh)


def mesh_files(twin: Twin) -> dict[str, tuple[str, trimesh.Trimesh]]:
    """{mesh name: (file name, mesh)} of every link's visual and collision meshes."""
    out = {}
    for lk in twin.links:
        out[f"{lk.name}_visual"] = (f"{lk.name}_visual.stl", lk.visual)
        for c, hull in enumerate(lk.collision):
            out[f"{lk.name}_collision_{c}"] = (f"{lk.name}_collision_{c}.stl", hull)
    return out


def header(twin: Twin, fmt: str) -> str:
    """The XML comment at the top of an MJCF or URDF file: units, joint zero, meshes."""
    units = "metres" if twin.metric else "MODEL UNITS written as metres (the scale was not known)"
    return (f"<!-- {fmt} digital twin written by artrecon.export. Units: {units}. Joint zero = "
            "configuration A (the reconstruction's points); positive values move toward "
            "configuration B. Meshes: visual = voxel surface of each link's points, collision "
            "= convex hulls of k-means clusters. -->\n")


def write_robot(twin: Twin, path: str | Path, text_fn, *, overwrite: bool = True,
                protect=()) -> list[Path]:
    """Write a robot file (``text_fn(twin, meshdir)``: MJCF or URDF text) at ``path`` with the
    twin's meshes in ``<stem>_meshes/`` beside it, whole or not at all: meshes first, the robot
    file last (:func:`artrecon.files.write_files_atomic`; ``overwrite`` and ``protect`` as there).
    Returns every file written, the robot file last."""
    path = Path(path)
    meshdir = f"{path.stem}_meshes"

    def files():
        for _, (fname, mesh) in mesh_files(twin).items():
            yield path.parent / meshdir / fname, mesh_bytes(mesh)
        yield path, text_fn(twin, meshdir).encode()

    return write_files_atomic(files(), overwrite=overwrite, protect=protect)
