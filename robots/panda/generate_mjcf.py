"""Write robots/panda/panda.xml (and copy its meshes and URDF) from example-robot-data's Panda.

The kinematics, joint limits, masses and inertias are those of the Franka Emika Panda URDF that
example-robot-data ships (``robots/panda_description/urdf/panda.urdf``, from franka_ros); the
collision meshes (binary STL) are copied into ``assets/`` and serve both as drawn and as contact
shapes (MuJoCo cannot read the package's .dae visual meshes). The URDF is copied beside the MJCF
as ``panda.urdf``: :mod:`sim.robot` builds the pinocchio model from that same file, so MuJoCo and
pinocchio share one source, and nothing reads the installed package at run time. The fingers are
welded open (the URDF's finger joints at 0.04 m); the camera and the grasp site come from
:mod:`sim.robot` (``PANDA_T_HAND_CAMERA``, ``PANDA_GRASP_OFFSET``). Drive gains: README.md.

Run from the repository root (needs example-robot-data installed)::

    python robots/panda/generate_mjcf.py          # rewrite panda.xml, assets/ and panda.urdf
    python robots/panda/generate_mjcf.py --check  # exit 1 if any of them is stale
"""

from __future__ import annotations

import argparse
import importlib.metadata
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from sim.robot import (  # noqa: E402
    CAMERA_FOCAL_PX,
    CAMERA_HEIGHT,
    CAMERA_WIDTH,
    PANDA,
    PANDA_FINGER_OPENING,
    PANDA_GRASP_OFFSET,
    PANDA_T_HAND_CAMERA,
)

HERE = Path(__file__).resolve().parent
OUT = HERE / "panda.xml"
#: Where example-robot-data keeps the Panda, inside its installed distribution.
PACKAGE_DIR = "cmeel.prefix/share/example-robot-data/robots/panda_description"
MESHES = ("link0", "link1", "link2", "link3", "link4", "link5", "link6", "link7", "hand",
          "finger")
# Drive: joint armature and damping, position-servo gains (N m/rad, N m s/rad) per joint: the
# values of MuJoCo Menagerie's franka_emika_panda (armature 0.1, damping 1; kp 4500/3500/2000),
# with gravity compensation so that the servos hold a pose without a steady-state error.
ARMATURE, DAMPING = 0.1, 1.0
KP = (4500.0, 4500.0, 3500.0, 3500.0, 2000.0, 2000.0, 2000.0)
KV = (450.0, 450.0, 350.0, 350.0, 200.0, 200.0, 200.0)


def package_dir() -> Path:
    """The installed example-robot-data's panda_description folder."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as err:
        raise SystemExit("example-robot-data is not installed; `pip install example-robot-data` "
                         "(only needed to regenerate robots/panda)") from err
    path = Path(dist.locate_file(PACKAGE_DIR))
    if not (path / "urdf" / "panda.urdf").is_file():
        raise SystemExit(f"{path}: no urdf/panda.urdf in example-robot-data {dist.version}")
    return path


def _f(*values: float) -> str:
    return " ".join(f"{float(v):.17g}" for v in values)


def _origin(el: ET.Element | None) -> np.ndarray:
    T = np.eye(4)
    if el is None:
        return T
    xyz = [float(v) for v in el.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in el.get("rpy", "0 0 0").split()]
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()  # URDF: Rz(y) Ry(p) Rx(r)
    T[:3, 3] = xyz
    return T


def _pose_attrs(T: np.ndarray) -> str:
    out = f'pos="{_f(*T[:3, 3])}"' if np.any(np.abs(T[:3, 3]) > 0) else ""
    if not np.allclose(T[:3, :3], np.eye(3), atol=1e-15):
        x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
        out += f' quat="{_f(w, x, y, z)}"'
    return out.strip()


def _inertial(link: ET.Element, indent: str) -> str:
    inertial = link.find("inertial")
    mass = float(inertial.find("mass").get("value"))
    if mass <= 0:
        return ""
    T = _origin(inertial.find("origin"))
    i = inertial.find("inertia")
    full = [float(i.get(k)) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")]
    return (f'{indent}<inertial pos="{_f(*T[:3, 3])}" mass="{_f(mass)}" '
            f'fullinertia="{_f(*full)}"/>')


def _camera_line(T_link7_camera: np.ndarray, indent: str) -> str:
    R_gl = T_link7_camera[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # MuJoCo cameras look down -z
    pixel = 5.6e-6  # sensor pixel pitch (m), as the PUMA's; only focal / pitch matters
    return (f'{indent}<camera name="{PANDA.camera}" pos="{_f(*T_link7_camera[:3, 3])}" '
            f'xyaxes="{_f(*R_gl[:, 0], *R_gl[:, 1])}" resolution="{CAMERA_WIDTH} {CAMERA_HEIGHT}" '
            f'sensorsize="{_f(CAMERA_WIDTH * pixel, CAMERA_HEIGHT * pixel)}" '
            f'focalpixel="{_f(CAMERA_FOCAL_PX, CAMERA_FOCAL_PX)}" principalpixel="0 0"/>')


def build(urdf_text: str) -> str:
    """The MJCF text of the Panda from the URDF text."""
    root = ET.fromstring(urdf_text)
    links = {el.get("name"): el for el in root.findall("link")}
    joints = {el.get("name"): el for el in root.findall("joint")}
    child_joint = {j.find("parent").get("link"): [] for j in joints.values()}
    for j in joints.values():
        child_joint[j.find("parent").get("link")].append(j)

    lines = [
        "<!-- Franka Emika Panda from example-robot-data's URDF (franka_ros). GENERATED by",
        "     robots/panda/generate_mjcf.py: edit that script, not this file.",
        "     Sources of every number: README.md. -->",
        '<mujoco model="panda">',
        '  <compiler angle="radian" autolimits="true"/>',
        "",
        "  <asset>",
        '    <material name="white" rgba="0.92 0.92 0.9 1"/>',
        '    <material name="dark" rgba="0.25 0.25 0.27 1"/>',
    ]
    lines += [f'    <mesh name="{m}" file="assets/{m}.stl"/>' for m in MESHES]
    lines += [
        "  </asset>",
        "",
        "  <default>",
        '    <default class="panda">',
        f'      <joint type="hinge" axis="0 0 1" armature="{_f(ARMATURE)}" '
        f'damping="{_f(DAMPING)}" actuatorgravcomp="true"/>',
        '      <position inheritrange="1"/>',
        '      <default class="visual">',
        '        <geom type="mesh" contype="0" conaffinity="0" group="2" density="0"/>',
        "      </default>",
        '      <default class="collision">',
        '        <geom group="3" rgba="0.8 0.2 0.2 0.3"/>',
        "      </default>",
        "    </default>",
        "  </default>",
        "",
        "  <worldbody>",
    ]

    def mesh_geoms(name: str, material: str, indent: str, extra: str = "") -> list[str]:
        attrs = f" {extra}" if extra else ""
        return [f'{indent}<geom class="visual" mesh="{name}" material="{material}"{attrs}/>',
                f'{indent}<geom class="collision" type="mesh" mesh="{name}"{attrs}/>']

    # base link0, then the chain of revolute joints panda_joint1..7 (each child link a body)
    indent = "    "
    lines.append(f'{indent}<body name="{PANDA.base_body}" childclass="panda">')
    lines.append(_inertial(links["panda_link0"], indent + "  "))
    lines += mesh_geoms("link0", "white", indent + "  ")
    link = "panda_link0"
    for k in range(1, 8):
        (j,) = [j for j in child_joint[link] if j.get("type") == "revolute"]
        assert j.get("name") == f"panda_joint{k}", j.get("name")
        assert j.find("axis").get("xyz").split() == ["0", "0", "1"]
        child = j.find("child").get("link")
        lim = j.find("limit")
        indent += "  "
        T = _origin(j.find("origin"))
        lines.append(f'{indent}<body name="link{k}" {_pose_attrs(T)} gravcomp="1">'.replace(
            '" >', '">'))
        lines.append(_inertial(links[child], indent + "  "))
        lines.append(f'{indent}  <joint name="{PANDA.joints[k - 1]}" '
                     f'range="{_f(float(lim.get("lower")), float(lim.get("upper")))}"/>')
        lines += mesh_geoms(f"link{k}", "dark" if k == 7 else "white", indent + "  ")
        link = child
    # link7 -> (joint8, fixed) link8 -> (hand joint, fixed) hand: welded, one body "hand"
    (j8,) = child_joint["panda_link7"]
    (jh,) = child_joint[j8.find("child").get("link")]
    T_link7_hand = _origin(j8.find("origin")) @ _origin(jh.find("origin"))
    T_link7_camera = T_link7_hand @ PANDA_T_HAND_CAMERA
    T_link7_grasp = T_link7_hand.copy()
    T_link7_grasp[:3, 3] = T_link7_hand[:3, :3] @ PANDA_GRASP_OFFSET + T_link7_hand[:3, 3]
    lines.append(f'{indent}  <site name="{PANDA.grasp_site}" {_pose_attrs(T_link7_grasp)} '
                 f'size="0.01" rgba="1 0.3 0.1 1" group="4"/>')
    lines.append(f'{indent}  <site name="flange" size="0.01" rgba="0.1 0.3 1 1" group="4"/>')
    lines.append(_camera_line(T_link7_camera, indent + "  "))
    lines.append(f'{indent}  <body name="hand" {_pose_attrs(T_link7_hand)} gravcomp="1">')
    lines.append(_inertial(links["panda_hand"], indent + "    "))
    lines += mesh_geoms("hand", "white", indent + "    ")
    # camera housing: a small dark box behind the lens (drawn and colliding)
    housing = PANDA_T_HAND_CAMERA.copy()
    housing[:3, 3] -= 0.02 * housing[:3, 2]
    for cls in ("visual", "collision"):
        mat = ' material="dark"' if cls == "visual" else ""
        lines.append(f'{indent}    <geom class="{cls}" type="box" size="0.045 0.013 0.02" '
                     f'{_pose_attrs(housing)}{mat}/>')
    for fj in (j for j in child_joint["panda_hand"] if j.get("type") == "prismatic"):
        flink = links[fj.find("child").get("link")]
        axis = np.array([float(v) for v in fj.find("axis").get("xyz").split()])
        T = _origin(fj.find("origin"))
        T[:3, 3] += axis * PANDA_FINGER_OPENING  # welded open
        name = "left_finger" if "left" in flink.get("name") else "right_finger"
        lines.append(f'{indent}    <body name="{name}" {_pose_attrs(T)} gravcomp="1">')
        lines.append(_inertial(flink, indent + "      "))
        vis = _origin(flink.find("visual").find("origin"))
        lines.append(f'{indent}      <geom class="visual" mesh="finger" material="dark" '
                     f'{_pose_attrs(vis)}/>'.replace(' />', '/>'))
        for col in flink.findall("collision"):
            Tc = _origin(col.find("origin"))
            size = np.array([float(v) for v in col.find("geometry/box").get("size").split()]) / 2
            lines.append(f'{indent}      <geom class="collision" type="box" size="{_f(*size)}" '
                         f'{_pose_attrs(Tc)}/>')
        lines.append(f"{indent}    </body>")
    lines.append(f"{indent}  </body>")
    for _ in range(7):
        lines.append(f"{indent}</body>")
        indent = indent[:-2]
    lines.append(f"{indent}</body>")
    lines += ["  </worldbody>", "", "  <actuator>"]
    for name, kp, kv in zip(PANDA.joints, KP, KV, strict=True):
        lines.append(f'    <position class="panda" name="{name}" joint="{name}" kp="{_f(kp)}" '
                     f'kv="{_f(kv)}"/>')
    lines += ["  </actuator>", "", "  <keyframe>",
              f'    <key name="home" qpos="{_f(*PANDA.home)}" ctrl="{_f(*PANDA.home)}"/>',
              "  </keyframe>", "</mujoco>", ""]
    return "\n".join(line for line in lines if line)


def outputs() -> dict[Path, bytes]:
    """Every generated file and its content."""
    src = package_dir()
    urdf = (src / "urdf" / "panda.urdf").read_bytes()
    out = {HERE / "panda.urdf": urdf, OUT: build(urdf.decode()).encode()}
    for m in MESHES:
        out[HERE / "assets" / f"{m}.stl"] = (src / "meshes" / "collision" / f"{m}.stl").read_bytes()
    out[HERE / "assets" / "LICENSE"] = (src / "LICENSE").read_bytes()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the files are stale")
    args = parser.parse_args()
    stale = []
    for path, content in outputs().items():
        if args.check:
            if not path.is_file() or path.read_bytes() != content:
                stale.append(path)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(content)
            print(f"wrote {path} ({len(content)} bytes)")
    if stale:
        print("stale: " + ", ".join(str(p) for p in stale) + "; run robots/panda/generate_mjcf.py")
        sys.exit(1)


if __name__ == "__main__":
    main()
