"""Small articulated objects written as a user would bring them (for tests/test_author*.py).

- :func:`write_partnet_chest`: a PartNet-Mobility-style ``mobility.urdf`` (an empty ``base`` link,
  the body fixed to it with PartNet's y-up to z-up turn, one OBJ per panel in
  ``textured_objs/`` without texture coordinates, child link frames at the joint with the meshes
  offset back): a box carcass, a lid on a revolute joint at its back edge and a drawer on a
  prismatic joint, both with handles. Units about 1 (PartNet-Mobility normalises its objects).
- :func:`write_mjcf_cabinet`: an MJCF cabinet with a hinged door, meshes as binary STL in
  millimetres scaled by ``<mesh scale="0.001 ...">``, body orientations as ``euler`` in degrees,
  a free joint on the root (as many MJCF objects have), visual geoms and collision boxes apart.

Both come with their true joint axes in the z-up world of the object, for the tests to compare.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

#: PartNet-Mobility's turn of its y-up meshes to z-up: the fixed joint from ``base`` has
#: rpy = (pi/2, 0, -pi/2), so link x = -world y, link y = world z, link z = -world x.
R_FIX = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # world <- link


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


def _write_obj(path: Path, m: trimesh.Trimesh, R: np.ndarray, offset=(0.0, 0.0, 0.0)) -> None:
    """Vertices mapped by R (link <- z-up world) then shifted: positions and faces only."""
    v = (m.vertices @ R.T) + np.asarray(offset)
    lines = [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v]
    lines += [f"f {a} {b} {c}" for a, b, c in m.faces + 1]
    path.write_text("\n".join(lines) + "\n")


#: The chest in its z-up frame (units ~1): carcass 0.8 deep (x), 1.0 wide (y), 0.66 high.
CHEST_CARCASS = {
    "bottom": ((-0.4, -0.5, 0.0), (0.4, 0.5, 0.04)),
    "left": ((-0.4, 0.46, 0.04), (0.4, 0.5, 0.66)),
    "right": ((-0.4, -0.5, 0.04), (0.4, -0.46, 0.66)),
    "back": ((-0.4, -0.46, 0.04), (-0.36, 0.46, 0.66)),
    "shelf": ((-0.36, -0.46, 0.30), (0.4, 0.46, 0.34)),
    "front": ((0.36, -0.46, 0.34), (0.4, 0.46, 0.66)),
}
CHEST_LID = {"panel": ((-0.42, -0.52, 0.66), (0.42, 0.52, 0.70)),
             "handle": ((0.42, -0.12, 0.62), (0.47, 0.12, 0.70))}
CHEST_DRAWER = {
    "front": ((0.36, -0.45, 0.05), (0.40, 0.45, 0.29)),
    "floor": ((-0.32, -0.42, 0.05), (0.36, 0.42, 0.07)),
    "left": ((-0.32, 0.39, 0.07), (0.36, 0.42, 0.24)),
    "right": ((-0.32, -0.42, 0.07), (0.36, -0.39, 0.24)),
    "back": ((-0.32, -0.39, 0.07), (-0.29, 0.39, 0.24)),
    "handle": ((0.40, -0.15, 0.15), (0.47, 0.15, 0.19)),
}
#: Lid hinge: the carcass's back top edge, the lid lifting its front for positive values.
CHEST_HINGE_POINT = np.array([-0.42, 0.0, 0.66])
CHEST_HINGE_AXIS = np.array([0.0, -1.0, 0.0])
CHEST_SLIDE_AXIS = np.array([1.0, 0.0, 0.0])


def write_partnet_chest(folder: Path) -> Path:
    """Write ``folder/mobility.urdf`` and ``folder/textured_objs/*.obj``; returns the URDF."""
    folder = Path(folder)
    objs = folder / "textured_objs"
    objs.mkdir(parents=True, exist_ok=True)
    R = R_FIX.T  # link <- world
    hinge_link = R @ CHEST_HINGE_POINT
    files = {}
    k = 0
    for part, boxes in (("carcass", CHEST_CARCASS), ("lid", CHEST_LID), ("drawer", CHEST_DRAWER)):
        files[part] = []
        for lo, hi in boxes.values():
            name = f"original-{k}.obj"
            # the lid's frame sits on its hinge (PartNet style): its meshes are offset back
            offset = -hinge_link if part == "lid" else np.zeros(3)
            _write_obj(objs / name, _box(lo, hi), R, offset)
            files[part].append(name)
            k += 1

    def link(name: str, part: str, origin=(0.0, 0.0, 0.0)) -> str:
        xyz = " ".join(f"{v:.6f}" for v in origin)
        out = [f'  <link name="{name}">']
        for i, f in enumerate(files[part]):
            for tag in ("visual", "collision"):
                out += [f'    <{tag} name="{part}-{i}">', f'      <origin xyz="{xyz}"/>',
                        f'      <geometry><mesh filename="textured_objs/{f}"/></geometry>',
                        f"    </{tag}>"]
        return "\n".join(out + ["  </link>"])

    axis_lid = " ".join(f"{v:g}" for v in R @ CHEST_HINGE_AXIS)
    axis_drawer = " ".join(f"{v:g}" for v in R @ CHEST_SLIDE_AXIS)
    hinge_xyz = " ".join(f"{v:.6f}" for v in hinge_link)
    text = f"""<?xml version="1.0" ?>
<robot name="partnet_chest">
  <link name="base"/>
{link("link_0", "drawer")}
  <joint name="joint_0" type="prismatic">
    <origin xyz="0 0 0"/>
    <axis xyz="{axis_drawer}"/>
    <child link="link_0"/>
    <parent link="link_2"/>
    <limit lower="0" upper="0.5"/>
  </joint>
{link("link_1", "lid")}
  <joint name="joint_1" type="revolute">
    <origin xyz="{hinge_xyz}"/>
    <axis xyz="{axis_lid}"/>
    <child link="link_1"/>
    <parent link="link_2"/>
    <limit lower="0" upper="1.6"/>
  </joint>
{link("link_2", "carcass")}
  <joint name="joint_2" type="fixed">
    <origin rpy="1.570796326794897 0 -1.570796326794897" xyz="0 0 0"/>
    <child link="link_2"/>
    <parent link="base"/>
  </joint>
</robot>
"""
    path = folder / "mobility.urdf"
    path.write_text(text)
    return path


#: The MJCF cabinet in millimetres (its meshes), z-up: 240 deep (x), 300 wide (y), 320 high,
#: front at +x, a door on a vertical hinge at the front's -y edge opening outwards.
CABINET_MM = {
    "bottom": ((-120, -150, 0), (120, 150, 14)),
    "top": ((-120, -150, 306), (120, 150, 320)),
    "left": ((-120, 136, 14), (120, 150, 306)),
    "right": ((-120, -150, 14), (120, -136, 306)),
    "back": ((-120, -136, 14), (-106, 136, 306)),
    "shelf": ((-106, -136, 150), (120, 136, 160)),
}
#: The door in its own frame (origin on the hinge line, millimetres; the frame is turned by
#: euler="180 0 0" in the cabinet, so its -y is the cabinet's +y and its +z the cabinet's -z):
#: a panel over the lower compartment and a bar handle near its free edge.
DOOR_MM = {"panel": ((-14, -272, -68), (0, -2, 68)),
           "post_low": ((0, -248, -50), (16, -236, -38)),
           "post_high": ((0, -248, 38), (16, -236, 50)),
           "bar": ((16, -252, -60), (28, -232, 60))}
#: The door's hinge in the cabinet's (z-up, unturned) frame, metres, and its axis there: the
#: joint's axis "0 0 1" of the turned door frame is the cabinet's -z, so positive values swing
#: the door outwards (+x) from its -y edge.
CABINET_HINGE_POINT = np.array([0.12, -0.136, 0.082])
CABINET_HINGE_AXIS = np.array([0.0, 0.0, -1.0])


def _boxes_xml(boxes, flip_xy: bool = False) -> str:
    out = []
    for name, (lo, hi) in boxes.items():
        lo, hi = np.asarray(lo, float) / 1000, np.asarray(hi, float) / 1000
        c, h = (lo + hi) / 2, (hi - lo) / 2
        if flip_xy:
            c = c * [-1, -1, 1]
        out.append(f'<geom name="{name}_col" type="box" pos="{c[0]:g} {c[1]:g} {c[2]:g}" '
                   f'size="{h[0]:g} {h[1]:g} {h[2]:g}" group="3"/>')
    return "\n".join(out)


def write_mjcf_cabinet(folder: Path) -> Path:
    """Write ``folder/cabinet.xml`` and ``folder/meshes/*.stl``; returns the MJCF.

    Orientations are euler angles in degrees: the root body is turned by 90 deg about z and its
    child (the carcass, welded) back by -90; the door is turned by 180 deg about x, its handle's
    collision boxes sit in a welded child body turned by 180 deg about z. A reader that ignored
    any of them would put the door's hinge elsewhere. The root has a free joint (dropped on
    import) and the file a floor plane and a light (left out).
    """
    folder = Path(folder)
    meshes = folder / "meshes"
    meshes.mkdir(parents=True, exist_ok=True)
    body = trimesh.util.concatenate([_box(lo, hi) for lo, hi in CABINET_MM.values()])
    door = trimesh.util.concatenate([_box(lo, hi) for lo, hi in DOOR_MM.values()])
    (meshes / "carcass.stl").write_bytes(trimesh.exchange.stl.export_stl(body))
    (meshes / "door.stl").write_bytes(trimesh.exchange.stl.export_stl(door))
    panel = {"panel": DOOR_MM["panel"]}
    handle = {k: v for k, v in DOOR_MM.items() if k != "panel"}
    hp = CABINET_HINGE_POINT
    text = f"""<mujoco model="mm_cabinet">
  <compiler angle="degree" meshdir="meshes"/>
  <asset>
    <mesh name="carcass" file="carcass.stl" scale="0.001 0.001 0.001"/>
    <mesh name="door" file="door.stl" scale="0.001 0.001 0.001"/>
  </asset>
  <default>
    <default class="vis"><geom type="mesh" contype="0" conaffinity="0" group="1"/></default>
  </default>
  <worldbody>
    <light pos="0 0 3"/>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="cabinet" pos="0.3 -0.2 0.1" euler="0 0 90">
      <freejoint name="free"/>
      <body name="carcass_frame" euler="0 0 -90">
        <geom class="vis" mesh="carcass" rgba="0.7 0.6 0.5 1"/>
        {_boxes_xml(CABINET_MM)}
        <body name="door" pos="{hp[0]:g} {hp[1]:g} {hp[2]:g}" euler="180 0 0">
          <joint name="door_hinge" type="hinge" axis="0 0 1" range="0 100" damping="0.1"/>
          <geom class="vis" mesh="door" rgba="0.6 0.5 0.4 1"/>
          {_boxes_xml(panel)}
          <body name="door_handle" euler="0 0 180">
            {_boxes_xml(handle, flip_xy=True)}
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
    path = folder / "cabinet.xml"
    path.write_text(text)
    return path
