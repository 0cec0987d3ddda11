"""The twin as a URDF file: a ``world`` link, a fixed joint welding the root to it, one link per
model link (inertial, visual and collision meshes), revolute or prismatic joints with limits."""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

from scipy.spatial.transform import Rotation

from artrecon.export.robotfile import header, number, numbers, write_robot
from artrecon.export.twin import ExportConfig, Twin, build_twin
from artrecon.model import ArticulatedModel

__all__ = ["URDF_EFFORT", "URDF_VELOCITY", "urdf_string", "export_urdf"]

#: URDF needs effort (N or N m) and velocity (rad/s or m/s) on every limit; the twin cannot know
#: its actuators, so generous placeholders that never bind in a kinematic use.
URDF_EFFORT = 100.0
URDF_VELOCITY = 10.0


def urdf_string(twin: Twin, meshdir: str) -> str:
    """The URDF text of a twin whose meshes are in `meshdir` (relative to the file)."""
    out = ['<?xml version="1.0"?>\n', header(twin, "URDF"),
           f"<robot name={quoteattr(twin.name)}>\n", '  <link name="world"/>\n']
    T = twin.T_world_base
    rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")  # URDF rpy: fixed axes x, y, z
    root = twin.links[twin.root].name
    out.append(f'  <joint name="{root}_weld" type="fixed">\n    <parent link="world"/>\n'
               f'    <child link="{root}"/>\n'
               f'    <origin xyz="{numbers(T[:3, 3])}" rpy="{numbers(rpy)}"/>\n'
               "  </joint>\n")
    for lk in twin.links:
        I = lk.inertia
        out.append(f'  <link name="{lk.name}">\n    <inertial>\n'
                   f'      <origin xyz="{numbers(lk.com)}" rpy="0 0 0"/>\n'
                   f'      <mass value="{number(lk.mass)}"/>\n'
                   f'      <inertia ixx="{number(I[0, 0])}" ixy="{number(I[0, 1])}" '
                   f'ixz="{number(I[0, 2])}" '
                   f'iyy="{number(I[1, 1])}" iyz="{number(I[1, 2])}" izz="{number(I[2, 2])}"/>\n'
                   "    </inertial>\n")
        out.append(f'    <visual>\n      <geometry>'
                   f'<mesh filename="{meshdir}/{lk.name}_visual.stl"/></geometry>\n'
                   f'      <material name="{lk.name}"><color rgba="{numbers(lk.rgba)}"/>'
                   "</material>\n    </visual>\n")
        for c in range(len(lk.collision)):
            out.append(f'    <collision>\n      <geometry><mesh filename="{meshdir}/{lk.name}_'
                       f'collision_{c}.stl"/></geometry>\n    </collision>\n')
        out.append("  </link>\n")
    for j in twin.joints:
        out.append(f'  <joint name="{j.name}" type="{j.type}">\n'
                   f'    <parent link="{twin.links[j.parent].name}"/>\n'
                   f'    <child link="{twin.links[j.child].name}"/>\n'
                   f'    <origin xyz="{numbers(j.origin_in_parent)}" rpy="0 0 0"/>\n'
                   f'    <axis xyz="{numbers(j.axis)}"/>\n'
                   f'    <limit lower="{number(j.lower)}" upper="{number(j.upper)}" '
                   f'effort="{number(URDF_EFFORT)}" '
                   f'velocity="{number(URDF_VELOCITY)}"/>\n  </joint>\n')
    out.append("</robot>\n")
    return "".join(out)


def export_urdf(model: ArticulatedModel | Twin, path: str | Path,
                config: ExportConfig | None = None, *, overwrite: bool = True,
                protect=()) -> list[Path]:
    """Write the model as a URDF file with its meshes in ``<stem>_meshes/`` beside it. See
    export_mjcf.

    Mesh file names are relative to the URDF's folder. ``pin.buildModelFromUrdf`` (kinematics,
    inertias) reads no mesh; pinocchio 4.1's ``pin.buildGeomFromUrdf`` resolves relative mesh
    paths against ``package_dirs``, so pass ``package_dirs=[<the URDF's folder>]``.
    """
    twin = model if isinstance(model, Twin) else build_twin(model, config, Path(path).stem)
    return write_robot(twin, path, urdf_string, overwrite=overwrite, protect=protect)
