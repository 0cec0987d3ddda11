"""The twin as an MJCF file (MuJoCo): one body per link (the root welded to the world), hinge or
slide joints with limits, exact inertias, visual and collision meshes, and keyframes
``configuration_a`` and ``configuration_b``."""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
from scipy.spatial.transform import Rotation

from artrecon.export.robotfile import header, mesh_files, number, numbers, write_robot
from artrecon.export.twin import ExportConfig, Twin, build_twin
from artrecon.model import ArticulatedModel

__all__ = ["mjcf_string", "export_mjcf"]


def mjcf_string(twin: Twin, meshdir: str) -> str:
    """The MJCF text of a twin whose meshes are in `meshdir` (relative to the file)."""
    meshes = mesh_files(twin)
    out = [header(twin, "MJCF"), f"<mujoco model={quoteattr(twin.name)}>\n",
           f'  <compiler angle="radian" meshdir={quoteattr(meshdir)} inertiafromgeom="false" '
           'autolimits="true"/>\n\n  <asset>\n']
    for name, (fname, _) in meshes.items():
        out.append(f"    <mesh name={quoteattr(name)} file={quoteattr(fname)}/>\n")
    for lk in twin.links:
        out.append(f'    <material name="{lk.name}" rgba="{numbers(lk.rgba)}"/>\n')
    out.append("  </asset>\n\n  <default>\n"
               '    <default class="visual">\n'
               '      <geom type="mesh" contype="0" conaffinity="0" group="2" density="0"/>\n'
               "    </default>\n"
               '    <default class="collision">\n'
               '      <geom type="mesh" group="3" density="0"/>\n'
               "    </default>\n  </default>\n\n  <worldbody>\n")

    def body(k: int, pos: np.ndarray, quat: np.ndarray | None, joint, depth: int) -> None:
        lk = twin.links[k]
        ind = "  " * depth
        q = "" if quat is None else f' quat="{numbers(quat)}"'
        out.append(f'{ind}<body name="{lk.name}" pos="{numbers(pos)}"{q}>\n')
        if joint is not None:
            kind = "hinge" if joint.type == "revolute" else "slide"
            out.append(f'{ind}  <joint name="{joint.name}" type="{kind}" pos="0 0 0" '
                       f'axis="{numbers(joint.axis)}" '
                       f'range="{number(joint.lower)} {number(joint.upper)}"/>\n')
        I = lk.inertia
        out.append(f'{ind}  <inertial pos="{numbers(lk.com)}" mass="{number(lk.mass)}" '
                   'fullinertia="'
                   f'{numbers([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])}"/>\n')
        out.append(f'{ind}  <geom name="{lk.name}_visual" class="visual" mesh="{lk.name}_visual" '
                   f'material="{lk.name}"/>\n')
        for c in range(len(lk.collision)):
            out.append(f'{ind}  <geom name="{lk.name}_collision_{c}" class="collision" '
                       f'mesh="{lk.name}_collision_{c}" material="{lk.name}"/>\n')
        for cj in twin.children_of(k):
            body(cj.child, cj.origin_in_parent, None, cj, depth + 1)
        out.append(f"{ind}</body>\n")

    T = twin.T_world_base
    quat_xyzw = Rotation.from_matrix(T[:3, :3]).as_quat()
    body(twin.root, T[:3, 3], np.roll(quat_xyzw, 1), None, 2)  # MuJoCo quaternions are w x y z
    out.append("  </worldbody>\n")
    if twin.joints:
        # keyframes in body (= qpos) order, which is the depth-first order of the bodies above
        qa, qb = [], []

        def dfs(k: int) -> None:
            for cj in twin.children_of(k):
                qa.append(0.0)
                qb.append(cj.motion)
                dfs(cj.child)

        dfs(twin.root)
        out.append(f'\n  <keyframe>\n    <key name="configuration_a" qpos="{numbers(qa)}"/>\n'
                   f'    <key name="configuration_b" qpos="{numbers(qb)}"/>\n  </keyframe>\n')
    out.append("</mujoco>\n")
    return "".join(out)


def export_mjcf(model: ArticulatedModel | Twin, path: str | Path,
                config: ExportConfig | None = None, *, overwrite: bool = True,
                protect=()) -> list[Path]:
    """Write the model as an MJCF file with its meshes in ``<stem>_meshes/`` beside it.

    Parameters
    ----------
    model : ArticulatedModel or Twin
    path : path of the .xml file
    config : ExportConfig, optional
    overwrite : bool
        Replace existing files (False: InputError naming them, nothing written).
    protect : iterable of path
        Inputs never to be written over (the command passes the model file).

    Returns
    -------
    paths : list of Path
        Every file written, the MJCF file last.
    """
    twin = model if isinstance(model, Twin) else build_twin(model, config, Path(path).stem)
    return write_robot(twin, path, mjcf_string, overwrite=overwrite, protect=protect)
