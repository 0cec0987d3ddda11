"""The twin as one PLY file per link: its points in the world frame at configuration A (metres,
64-bit floats), with normals and colours when the model has them."""

from __future__ import annotations

from pathlib import Path

from artrecon.errors import InputError
from artrecon.export.twin import ExportConfig, Twin, build_twin
from artrecon.files import ply_bytes, write_files_atomic
from artrecon.model import ArticulatedModel

__all__ = ["export_ply"]


def export_ply(model: ArticulatedModel | Twin, out_dir: str | Path,
               config: ExportConfig | None = None, *, overwrite: bool = True,
               protect=()) -> list[Path]:
    """Write one PLY per link into `out_dir` (``<link name>.ply``): the link's points in the
    world frame at configuration A (metres), with normals and colours when the model has them.
    ``overwrite`` and ``protect`` as for :func:`artrecon.export.mjcf.export_mjcf`. Returns the
    paths, in link order."""
    twin = model if isinstance(model, Twin) else build_twin(model, config, Path(out_dir).name)
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir} is a file; PLY export writes one file per link into a folder")
    R = twin.T_world_base[:3, :3]

    def files():
        for k, lk in enumerate(twin.links):
            normals = None if lk.normals is None else lk.normals @ R.T
            yield out_dir / f"{lk.name}.ply", ply_bytes(twin.points_in_world(k), normals,
                                                        lk.colours, precision="double")

    return write_files_atomic(files(), overwrite=overwrite, protect=protect)
