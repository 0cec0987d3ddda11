"""Write robots/puma560/puma560.xml from the published PUMA 560 parameters.

The kinematics (DH table, joint limits, camera mount) come from :mod:`sim.robot`, so MuJoCo and the
pinocchio model share one source; masses, centres of mass, inertias and drive parameters are the
Corke & Armstrong-Helouvry (1994) values listed below (see README.md for every number's source).

Run from the repository root::

    python robots/puma560/generate_mjcf.py          # rewrite puma560.xml
    python robots/puma560/generate_mjcf.py --check  # exit 1 if puma560.xml is stale
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from sim.robot import (  # noqa: E402
    CAMERA_FOCAL_PX,
    CAMERA_HEIGHT,
    CAMERA_WIDTH,
    PUMA560,
    PUMA560_GRASP_OFFSET,
    PUMA560_T_FLANGE_CAMERA,
)

OUT = Path(__file__).with_name("puma560.xml")

# Link masses (kg), centres of mass in DH frame i (m) and principal inertias about the centre of
# mass along DH frame i's axes (kg m^2): Corke & Armstrong-Helouvry 1994 (mdl_puma560, params 8/95).
# Link 1: the source gives m1 = 0 (its origin does not move); we assume 12 kg on the axis, which
# only matters for the rail. Its inertia about the joint axis is the published 0.35 kg m^2.
# Link 3: the published (0.066, 0.086, 0.0125) violates the triangle inequality of a rigid body
# (0.066 + 0.0125 < 0.086); Iyy is lowered to 0.0785, the largest physical value.
MASS = (12.0, 17.4, 4.8, 0.82, 0.34, 0.09)
COM = ((0.0, -0.1, 0.0), (-0.3638, 0.006, 0.2275), (-0.0203, -0.0141, 0.070), (0.0, 0.019, 0.0),
       (0.0, 0.0, 0.0), (0.0, 0.0, 0.032))
INERTIA = ((0.2, 0.35, 0.2), (0.13, 0.524, 0.539), (0.066, 0.0785, 0.0125),
           (1.8e-3, 1.3e-3, 1.8e-3), (0.3e-3, 0.4e-3, 0.3e-3), (0.15e-3, 0.15e-3, 0.04e-3))
# Motor inertia Jm (kg m^2), gear ratio G and viscous friction B (N m s/rad, at the motor), same
# source: armature = Jm G^2 and damping = B G^2 at the joint.
JM = (200e-6, 200e-6, 200e-6, 33e-6, 33e-6, 33e-6)
GEAR = (-62.6111, 107.815, -53.7063, 76.0364, 71.923, 76.686)
VISCOUS = (1.48e-3, 0.817e-3, 1.38e-3, 71.2e-6, 82.6e-6, 36.7e-6)
# Position servo gains (N m/rad, N m s/rad): about 6 Hz for the arm joints and 10 Hz for the wrist
# with the armature above, near critical damping (kv ~ 2 sqrt(kp I)).
KP = (4000.0, 4000.0, 3000.0, 600.0, 600.0, 300.0)
KV = (250.0, 300.0, 180.0, 25.0, 25.0, 15.0)

# Simple-shape geometry per body, in that body's frame (the frame of DH frame i-1 turned by the
# joint angle about its z). a2, a3, d3, d4 are the DH lengths, so links join where the table says.
DH = PUMA560.dh
A2, A3, D3, D4 = DH[1].a, DH[2].a, DH[2].d, DH[3].d
H0 = PUMA560.shoulder_height


def _f(*v: float) -> str:
    return " ".join(f"{x:.17g}" if abs(x) > 1e-15 else "0" for x in v)


def _geoms(indent: str, shapes: list[tuple[str, str, str]], material: str) -> list[str]:
    """Each shape twice: a visual geom and a collision geom."""
    lines = []
    for kind, size, where in shapes:
        lines.append(f'{indent}<geom class="visual" type="{kind}" size="{size}" {where} '
                     f'material="{material}"/>')
    for kind, size, where in shapes:
        lines.append(f'{indent}<geom class="collision" type="{kind}" size="{size}" {where}/>')
    return lines


SHAPES = {
    "base": [
        ("cylinder", "0.15 0.015", 'pos="0 0 0.015"'),
        ("cylinder", "0.09", f'fromto="0 0 0.03 0 0 {H0 - 0.22:.4f}"'),
    ],
    "link1": [
        ("cylinder", "0.085", 'fromto="0 0 -0.22 0 0 -0.05"'),
        ("cylinder", "0.1", 'fromto="0 0.09 0 0 -0.09 0"'),
    ],
    "link2": [
        ("capsule", "0.06", f'fromto="0 0 0 {A2} 0 0"'),
        ("cylinder", "0.065", f'fromto="{A2} 0 0 {A2} 0 {D3 - 0.06:.4f}"'),
    ],
    "link3": [
        ("cylinder", "0.06", f'fromto="0 0 {D3 - 0.06:.4f} 0 0 {D3 + 0.06:.4f}"'),
        ("capsule", "0.05", f'fromto="{A3} 0 {D3} {A3} 0.26 {D3}"'),
    ],
    "link4": [
        ("cylinder", "0.042", f'fromto="0 0 0.26 0 0 {D4 - 0.05:.4f}"'),
    ],
    "link5": [
        ("cylinder", "0.04", 'fromto="0 0 -0.045 0 0 0.045"'),
    ],
    "link6": [
        ("cylinder", "0.032", 'fromto="0 0 0.03 0 0 0.056"'),
        ("box", "0.045 0.02 0.012", 'pos="0 0 0.068"'),
        ("box", "0.008 0.012 0.03", 'pos="0.03 0 0.11"'),
        ("box", "0.008 0.012 0.03", 'pos="-0.03 0 0.11"'),
        ("box", "0.01 0.028 0.005", 'pos="0 -0.045 0.051"'),
        ("box", "0.02 0.014 0.014", 'pos="0 -0.075 0.054"'),
    ],
}
MATERIAL = {"base": "dark", "link1": "cream", "link2": "cream", "link3": "cream", "link4": "cream",
            "link5": "dark", "link6": "metal"}


def _camera_line(indent: str) -> str:
    T = PUMA560_T_FLANGE_CAMERA
    R_gl = T[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # MuJoCo cameras look down -z, +y up
    pixel = 5.6e-6  # sensor pixel pitch (m); only the ratio focal / pitch matters
    return (f'{indent}<camera name="{PUMA560.camera}" pos="{_f(*T[:3, 3])}" '
            f'xyaxes="{_f(*R_gl[:, 0], *R_gl[:, 1])}" resolution="{CAMERA_WIDTH} {CAMERA_HEIGHT}" '
            f'sensorsize="{_f(CAMERA_WIDTH * pixel, CAMERA_HEIGHT * pixel)}" '
            f'focalpixel="{_f(CAMERA_FOCAL_PX, CAMERA_FOCAL_PX)}" principalpixel="0 0"/>')


def generate() -> str:
    qlim = np.deg2rad(np.array(PUMA560.qlim_deg))
    lines = [
        "<!-- PUMA 560 (Unimation) from its standard DH parameters. GENERATED by",
        "     robots/puma560/generate_mjcf.py: edit that script, not this file.",
        "     Sources of every number: README.md. -->",
        '<mujoco model="puma560">',
        '  <compiler angle="radian" autolimits="true"/>',
        "",
        "  <asset>",
        '    <material name="cream" rgba="0.88 0.85 0.78 1"/>',
        '    <material name="dark" rgba="0.25 0.25 0.27 1"/>',
        '    <material name="metal" rgba="0.6 0.6 0.62 1"/>',
        "  </asset>",
        "",
        "  <default>",
        '    <default class="puma560">',
        '      <joint type="hinge" axis="0 0 1" actuatorgravcomp="true"/>',
        '      <position inheritrange="1"/>',
        '      <default class="visual">',
        '        <geom type="cylinder" contype="0" conaffinity="0" group="2"/>',
        "      </default>",
        '      <default class="collision">',
        '        <geom type="cylinder" group="3" rgba="0.8 0.2 0.2 0.3"/>',
        "      </default>",
        "    </default>",
        "  </default>",
        "",
        "  <worldbody>",
        f'    <body name="{PUMA560.base_body}" childclass="puma560">',
        '      <inertial pos="0 0 0.2" mass="28" diaginertia="0.6 0.6 0.15"/>',
    ]
    lines += _geoms("      ", SHAPES["base"], MATERIAL["base"])
    indent = "      "
    closers = []
    for i in range(6):
        name = f"link{i + 1}"
        if i == 0:
            where = f'pos="0 0 {_f(H0)}"'
        else:
            prev = DH[i - 1]
            where = f'pos="{_f(prev.a, 0.0, prev.d)}" euler="{_f(prev.alpha, 0.0, 0.0)}"'
        lines.append(f'{indent}<body name="{name}" {where} gravcomp="1">')
        indent += "  "
        # Inertial: the source gives it in DH frame i = this body's frame * Tz(d) Tx(a) Rx(alpha).
        link = DH[i]
        ca, sa = np.cos(link.alpha), np.sin(link.alpha)
        r = np.array(COM[i])
        com = np.array([link.a, 0.0, link.d]) + np.array(
            [r[0], ca * r[1] - sa * r[2], sa * r[1] + ca * r[2]])
        iquat = (np.cos(link.alpha / 2), np.sin(link.alpha / 2), 0.0, 0.0)
        lines.append(f'{indent}<inertial pos="{_f(*com)}" quat="{_f(*iquat)}" mass="{MASS[i]}" '
                     f'diaginertia="{_f(*INERTIA[i])}"/>')
        armature = JM[i] * GEAR[i] ** 2
        damping = VISCOUS[i] * GEAR[i] ** 2
        lines.append(f'{indent}<joint name="{PUMA560.joints[i]}" range="{_f(*qlim[i])}" '
                     f'armature="{armature:.4g}" damping="{damping:.4g}"/>')
        lines += _geoms(indent, SHAPES[name], MATERIAL[name])
        if i == 5:
            lines.append(f'{indent}<site name="{PUMA560.grasp_site}" '
                         f'pos="{_f(*PUMA560_GRASP_OFFSET)}" size="0.01" rgba="1 0.3 0.1 1" '
                         'group="4"/>')
            lines.append(f'{indent}<site name="flange" size="0.01" rgba="0.1 0.3 1 1" group="4"/>')
            lines.append(_camera_line(indent))
        closers.append(f"{indent[:-2]}</body>")
    lines += reversed(closers)
    lines += ["    </body>", "  </worldbody>", "", "  <actuator>"]
    for i, j in enumerate(PUMA560.joints):
        lines.append(f'    <position class="puma560" name="{j}" joint="{j}" kp="{KP[i]:g}" '
                     f'kv="{KV[i]:g}"/>')
    lines += ["  </actuator>", "", "  <keyframe>",
              f'    <key name="home" qpos="{_f(*PUMA560.home)}" ctrl="{_f(*PUMA560.home)}"/>',
              "  </keyframe>", "</mujoco>", ""]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="fail if puma560.xml is stale")
    args = parser.parse_args()
    text = generate()
    if args.check:
        if not OUT.exists() or OUT.read_text() != text:
            print(f"{OUT} is stale: run python robots/puma560/generate_mjcf.py")  # noqa: T201
            return 1
        return 0
    OUT.write_text(text)
    print(f"wrote {OUT}")  # noqa: T201
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
