"""``artrecon export MODEL --format mjcf|urdf|glb|ply --out PATH``: the command."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

import numpy as np

from artrecon.errors import ArtreconError, InputError
from artrecon.export.formats import FORMATS, SUFFIX, export_model
from artrecon.export.twin import COLLISION_CLUSTERS, DEFAULT_DENSITY, ExportConfig
from artrecon.model import ArticulatedModel

__all__ = ["add_export_parser", "check_export_target", "run_export", "export_main"]


def add_export_parser(subparsers=None) -> argparse.ArgumentParser:
    """The `export` command's parser: as a subparser of `subparsers` (from
    ArgumentParser.add_subparsers) or standalone when None. Its handler is in
    ``parser.get_default("handler")``: call ``handler(args)`` -> exit code."""
    kwargs = dict(
        description="Export an articulated model (JSON from the reconstruction) as MJCF, URDF, "
                    "GLB, or one PLY per link. Existing files are never replaced without "
                    "--overwrite, and the model file never.",
    )
    if subparsers is None:
        parser = argparse.ArgumentParser(prog="artrecon export", **kwargs)
    else:
        parser = subparsers.add_parser("export", help="export a model as MJCF/URDF/GLB/PLY",
                                       **kwargs)
    parser.add_argument("model", type=Path, help="model JSON written by ArticulatedModel.save")
    parser.add_argument("--format", required=True, choices=FORMATS, dest="format")
    parser.add_argument("--out", required=True, type=Path,
                        help="output file (.xml for mjcf, .urdf, .glb); a folder for ply")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace existing output files (never the model file)")
    parser.add_argument("--base-frame", default=None,
                        help="place the base at this pose of the model's frames "
                             "(e.g. T_world_model after registration)")
    parser.add_argument("--voxel-size", type=float, default=None,
                        help="voxel edge of the meshes in metres (default: from point spacing)")
    parser.add_argument("--density", type=float, default=DEFAULT_DENSITY,
                        help=f"link density, kg/m^3 (default {DEFAULT_DENSITY:g})")
    parser.add_argument("--collision-clusters", type=int, default=COLLISION_CLUSTERS,
                        help=f"convex hulls per link (default {COLLISION_CLUSTERS})")
    parser.add_argument("--glb-geometry", choices=("points", "mesh"), default="points")
    parser.add_argument("--seed", type=int, default=0)
    parser.set_defaults(handler=run_export)
    return parser


def _same(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_export_target(model_path: str | Path, fmt: str, out: str | Path,
                        overwrite: bool = False) -> None:
    """Refuse, before any work, an ``--out`` the export cannot write as asked.

    Raises
    ------
    InputError
        ``out`` is the model file itself; a folder where a file format writes a file (or a file
        where PLY writes a folder); or an existing file without ``overwrite``. (Each file of
        the export is checked again just before it is put in place:
        :class:`artrecon.files.StagedFiles`.)
    """
    model_path, out = Path(model_path), Path(out)
    suffix = SUFFIX.get(fmt) or ""
    if _same(out, model_path):
        raise InputError(f"--out {out} is the model file being exported; writing the {fmt} "
                         f"there would destroy the model. Name another path, e.g. "
                         f"{out.with_name('twin' + suffix)}")
    if fmt == "ply":
        if out.exists() and not out.is_dir():
            raise InputError(f"--out {out} is a file; PLY export writes one file per link into a "
                             "folder: name a folder (it is created if missing)")
        return
    if out.is_dir():
        raise InputError(f"--out {out} is a folder; name the {fmt.upper()} file to write, e.g. "
                         f"{out / ('twin' + suffix)}")
    if out.exists() and not overwrite:
        raise InputError(f"--out {out} exists; nothing was written. Choose another --out, or "
                         "pass --overwrite to replace it")


def run_export(args: argparse.Namespace) -> int:
    """Run the export command from parsed arguments; returns the exit code (0 done, 2 bad input
    or a failed write, 130 interrupted)."""
    overwrite = bool(getattr(args, "overwrite", False))
    try:
        config = ExportConfig(voxel_size=args.voxel_size, density=args.density,
                              collision_clusters=args.collision_clusters,
                              base_frame=args.base_frame, glb_geometry=args.glb_geometry,
                              seed=args.seed)
        check_export_target(args.model, args.format, args.out, overwrite)
        model = ArticulatedModel.load(args.model)
        bad = [k for k, lk in enumerate(model.links) if not np.all(np.isfinite(lk.points))]
        if bad:
            raise InputError(f"{args.model}: the points of link(s) {bad} hold non-finite "
                             "coordinates (NaN or inf), which no reconstruction writes: the file "
                             "is damaged or was edited; reconstruct again or restore it")
        paths = export_model(model, args.format, args.out, config, overwrite=overwrite,
                             protect=[args.model])
    except (ArtreconError, ValueError, OSError) as exc:
        # the command's own output (this is the CLI layer; the library above only logs)
        sys.stderr.write(f"artrecon export: error: {exc}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"artrecon export: interrupted; nothing was written to {args.out}\n")
        return 130
    sys.stdout.write(f"wrote {len(paths)} files: {paths[-1]}\n")
    return 0


def export_main(argv: list[str] | None = None) -> int:
    """`artrecon export MODEL --format mjcf|urdf|glb|ply --out PATH` as a standalone entry
    point; returns the exit code."""
    parser = add_export_parser()
    args = parser.parse_args(argv)
    return args.handler(args)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    raise SystemExit(export_main())
