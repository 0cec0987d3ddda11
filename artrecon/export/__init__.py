"""The recovered model as a digital twin: MJCF, URDF, GLB and PLY per link.

Rooms of the package (one job each)::

    twin.py       the model prepared for export: metres, link frames, joint limits (Twin,
                  build_twin, ExportConfig); the frames and units are described there
    mesh.py       each link's visual mesh (voxel surface), collision hulls and inertia
    robotfile.py  what the MJCF and URDF writers share (number format, mesh files, header)
    mjcf.py       export_mjcf: MuJoCo
    urdf.py       export_urdf: URDF (pinocchio, ROS)
    glb.py        export_glb: a glTF scene with the axes drawn
    ply.py        export_ply: one PLY per link
    formats.py    export_model: any of FORMATS
    cli.py        ``artrecon export MODEL --format mjcf|urdf|glb|ply --out PATH``

Writes are whole or not at all (:func:`artrecon.files.write_files_atomic`): every file is first
written to a temporary file beside its final path; only when all files are written are they
renamed into place (meshes first, the MJCF/URDF file last, so a model file never names a
missing mesh). The library's writers replace existing files (``overwrite=True``); the command
never replaces a file without ``--overwrite`` and never the model file it reads.

Usage::

    from artrecon import export as ex
    twin = ex.build_twin(model, ex.ExportConfig(base_frame="T_world_model"))
    ex.export_mjcf(twin, "out/twin.xml")
"""

from artrecon.export.cli import add_export_parser, check_export_target, export_main, run_export
from artrecon.export.formats import FORMATS, SUFFIX, export_model
from artrecon.export.glb import AXIS_RADIUS_FRACTION, AXIS_RGBA, export_glb, glb_scene
from artrecon.export.mesh import (
    CLOSING_ITERATIONS,
    MAX_VOXELS_PER_AXIS,
    MIN_CLUSTER_POINTS,
    SHRINK_MARGIN,
    SMOOTHING_ITERATIONS,
    SMOOTHING_LAMBDA,
    SMOOTHING_NU,
    VOXEL_SPACING_FACTOR,
    auto_voxel_size,
    collision_hulls,
    voxel_inertia,
    voxel_surface,
)
from artrecon.export.mjcf import export_mjcf, mjcf_string
from artrecon.export.ply import export_ply
from artrecon.export.twin import (
    COLLISION_CLUSTERS,
    DEFAULT_DENSITY,
    LIMIT_MARGIN_FRACTION,
    MAX_VISUAL_FACES,
    PALETTE,
    PRISMATIC_MARGIN_MIN_FRACTION,
    REVOLUTE_MARGIN_MIN,
    ExportConfig,
    Twin,
    TwinJoint,
    TwinLink,
    build_twin,
)
from artrecon.export.urdf import URDF_EFFORT, URDF_VELOCITY, export_urdf, urdf_string

__all__ = [
    "FORMATS",
    "SUFFIX",
    "ExportConfig",
    "TwinLink",
    "TwinJoint",
    "Twin",
    "build_twin",
    "auto_voxel_size",
    "voxel_surface",
    "collision_hulls",
    "voxel_inertia",
    "mjcf_string",
    "urdf_string",
    "glb_scene",
    "export_model",
    "export_mjcf",
    "export_urdf",
    "export_glb",
    "export_ply",
    "add_export_parser",
    "check_export_target",
    "run_export",
    "export_main",
    "AXIS_RGBA",
    "AXIS_RADIUS_FRACTION",
    "CLOSING_ITERATIONS",
    "COLLISION_CLUSTERS",
    "DEFAULT_DENSITY",
    "LIMIT_MARGIN_FRACTION",
    "MAX_VISUAL_FACES",
    "MAX_VOXELS_PER_AXIS",
    "MIN_CLUSTER_POINTS",
    "PALETTE",
    "PRISMATIC_MARGIN_MIN_FRACTION",
    "REVOLUTE_MARGIN_MIN",
    "SHRINK_MARGIN",
    "SMOOTHING_ITERATIONS",
    "SMOOTHING_LAMBDA",
    "SMOOTHING_NU",
    "URDF_EFFORT",
    "URDF_VELOCITY",
    "VOXEL_SPACING_FACTOR",
]
