"""One entry point for every export format: :func:`export_model`."""

from __future__ import annotations

import logging
from pathlib import Path

from artrecon.export.glb import export_glb
from artrecon.export.mjcf import export_mjcf
from artrecon.export.ply import export_ply
from artrecon.export.twin import ExportConfig
from artrecon.export.urdf import export_urdf
from artrecon.model import ArticulatedModel

log = logging.getLogger(__name__)

__all__ = ["FORMATS", "SUFFIX", "export_model"]

FORMATS = ("mjcf", "urdf", "glb", "ply")
#: The file name ending of each format's output ("ply" writes a folder).
SUFFIX = {"mjcf": ".xml", "urdf": ".urdf", "glb": ".glb", "ply": ""}


def export_model(model: ArticulatedModel, fmt: str, out: str | Path,
                 config: ExportConfig | None = None, *, overwrite: bool = True,
                 protect=()) -> list[Path]:
    """Export in one of FORMATS ("mjcf", "urdf", "glb", "ply"); `out` is the file (a folder for
    "ply"). ``overwrite``: replace existing files (False: InputError, nothing written);
    ``protect``: inputs never written over. Returns the files written."""
    writers = {"mjcf": export_mjcf, "urdf": export_urdf, "glb": export_glb, "ply": export_ply}
    if fmt not in writers:
        raise ValueError(f"format must be one of {FORMATS}, got {fmt!r}")
    paths = writers[fmt](model, out, config, overwrite=overwrite, protect=protect)
    log.info("exported %s: %d files, main %s", fmt, len(paths), paths[-1])
    return paths
