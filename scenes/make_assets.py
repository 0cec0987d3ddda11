"""Generate the textures and textured meshes of the stage and the bundled scenes.

Run from anywhere::

    python scenes/make_assets.py            # writes scenes/assets/
    python scenes/make_assets.py --out DIR  # writes elsewhere (the tests check determinism so)

This script only describes the parts (their shapes, atlas sizes and texel sizes); the machinery
(surface patches, atlas packing, OBJ writing, the textures) is :mod:`sim.assets`, which also
textures any mesh of your own (:func:`sim.assets.texture_mesh`; ``python -m sim.author import``
uses it for imported objects).

Everything is deterministic: one master seed, one derived seed per part (from the part's name),
numpy's PCG64 generator, OpenCV drawing. Each part is one OBJ mesh with UVs and one PNG texture.
Every face of every mesh has its own region of its texture atlas, so no piece of texture appears
twice anywhere in the world (a repeated pattern can make SfM fold a ring of cameras).

Geometry is in metres in the frame of the MJCF body that carries the mesh (the geoms that use
the meshes have no pos or quat). The z = 0 plane of an object's root body is the table top.

Texel size: the capture camera (fx = 554 px) at about 0.4 m sees about 0.7 mm per pixel at the
image centre and 1.4 mm per pixel for a 20 cm object filling half the image, so object parts get
0.5 - 1.2 mm per texel, the table about 1 mm and the far background (floor, walls, 1 - 2 m away)
4 - 7 mm. The achieved texel size of every part is printed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:  # run as a script: import this checkout's sim
    sys.path.insert(0, str(HERE.parent))

from sim.assets import (  # noqa: E402
    SEED,
    Part,
    Patch,
    bar,
    box,
    cylinder,
    generate_parts,
    quad,
)

# --------------------------------------------------------------------------------------------
# Parts. Object frames: z = 0 is the table top, the object's root body sits at the table centre.
# --------------------------------------------------------------------------------------------


def pliers_half(side: float, z0: float, z1: float) -> list[Patch]:
    """One half of a pair of pliers lying on the table, pivot at the origin, jaws along +x.

    ``side`` = -1: jaw on -y, handle on +y (the fixed half); +1: mirrored (the moving half).
    About 20 cm from jaw tip to handle end; handles 14 mm wide with a 3 mm thicker grip.
    """
    s = side
    out = cylinder((0.0, 0.0, (z0 + z1) / 2), 0.012, (z1 - z0) / 2)
    out += bar((0.006, s * 0.0045), (0.068, s * 0.0025), 0.009, z0, z1)  # jaw
    out += bar((-0.006, -s * 0.004), (-0.050, -s * 0.011), 0.012, z0, z1)  # handle neck
    grip_z0 = max(z0 - 0.0015, 0.0005)
    out += bar((-0.050, -s * 0.011), (-0.132, -s * 0.019), 0.015, grip_z0, z1 + 0.0015)  # grip
    return out


def truck_chassis() -> list[Patch]:
    """Chassis, cab and four wheels of a toy dump truck (about 30 x 14 x 17 cm), +x forward."""
    out = box((-0.14, -0.05, 0.045), (0.14, 0.05, 0.07))  # frame
    out += box((0.06, -0.065, 0.07), (0.15, 0.065, 0.17))  # cab
    out += box((0.14, -0.07, 0.035), (0.155, 0.07, 0.06))  # front bumper
    for x in (0.09, -0.08):
        for y in (0.065, -0.065):
            out += cylinder((x, y, 0.0355), 0.035, 0.015, axis="y")
    return out


def truck_bed() -> list[Patch]:
    """Open dump bed, 20.5 x 14 x 7.8 cm, 6 mm walls, with a lip over the cab to pull on."""
    x0, x1, y, z0, z1, t = -0.15, 0.055, 0.07, 0.072, 0.15, 0.006
    out = box((x0, -y, z0), (x1, y, z0 + 0.008))  # floor
    out += box((x0, -y, z0 + 0.008), (x1, -y + t, z1))  # right wall
    out += box((x0, y - t, z0 + 0.008), (x1, y, z1))  # left wall
    out += box((x0, -y + t, z0 + 0.008), (x0 + t, y - t, z1 - 0.02))  # tailgate (lower)
    out += box((x1 - t, -y + t, z0 + 0.008), (x1, y - t, z1))  # front wall
    out += box((x1, -0.05, z1 - 0.008), (x1 + 0.04, 0.05, z1))  # lip over the cab
    return out


def cabinet() -> list[Patch]:
    """A 24 x 30 x 30 cm cabinet, front at +x, a drawer opening at the top, 12 mm panels."""
    x0, x1, y, h, t = -0.12, 0.12, 0.15, 0.30, 0.012
    z0 = 0.0005
    out = box((x0, -y, z0), (x1, y, z0 + t), skip=("-z",))  # bottom
    out += box((x0, -y, h - t), (x1, y, h))  # top
    out += box((x0, -y, z0 + t), (x1, -y + t, h - t))  # right side
    out += box((x0, y - t, z0 + t), (x1, y, h - t))  # left side
    out += box((x0, -y + t, z0 + t), (x0 + t, y - t, h - t))  # back
    out += box((x0 + t, -y + t, 0.158), (x1, y - t, 0.17))  # shelf under the drawer
    out += box((x1 - t, -y + t, z0 + t), (x1, y - t, 0.158))  # fixed front below the drawer
    return out


def drawer() -> list[Patch]:
    """Drawer (front 27.2 x 11.3 cm, tray 20.8 cm deep) with a bar handle, closed position."""
    out = box((0.108, -0.136, 0.173), (0.12, 0.136, 0.286))  # front
    out += box((-0.10, -0.13, 0.174), (0.108, 0.13, 0.18))  # tray bottom
    out += box((-0.10, -0.13, 0.18), (0.108, -0.124, 0.26))  # tray right
    out += box((-0.10, 0.124, 0.18), (0.108, 0.13, 0.26))  # tray left
    out += box((-0.10, -0.124, 0.18), (-0.094, 0.124, 0.26))  # tray back
    for yy in (-0.05, 0.05):
        out += box((0.12, yy - 0.006, 0.224), (0.14, yy + 0.006, 0.236))  # handle posts
    out += box((0.14, -0.06, 0.222), (0.152, 0.06, 0.238))  # handle bar
    return out


def table() -> list[Patch]:
    """Round table: top radius 0.35 m, 4 cm thick (top face at z = 0.45), one leg."""
    top = cylinder((0.0, 0.0, 0.43), 0.35, 0.02, pieces=4, coarse=(1.0, 4.0, 1.0))
    return top + cylinder((0.0, 0.0, 0.21), 0.05, 0.21, caps=(False, False), coarse=(4, 4, 4))


def floor() -> list[Patch]:
    """Floor square 4 x 4 m at z = 0 (only its top face)."""
    return [quad([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]])]


def walls() -> list[Patch]:
    """Four walls 2.2 m high around the floor (inner faces only)."""
    h = 2.2
    return [
        quad([[-2, -2, 0], [-2, 2, 0], [-2, 2, h], [-2, -2, h]]),
        quad([[2, 2, 0], [2, -2, 0], [2, -2, h], [2, 2, h]]),
        quad([[2, -2, 0], [-2, -2, 0], [-2, -2, h], [2, -2, h]]),
        quad([[-2, 2, 0], [2, 2, 0], [2, 2, h], [-2, 2, h]]),
    ]


# Parts of the scenes of the method's wider object set (scissors, Barrett hand, scraper truck,
# hinged cabinet). Appended after the first scenes' parts; they do not change those parts' output.


def scissors_half(side: float, z0: float, z1: float) -> list[Patch]:
    """One half of a pair of scissors lying on the table, pivot at the origin, blade along +x.

    ``side`` = -1: blade edge on -y, handle ring on +y (the fixed half); +1: mirrored (the
    moving half). 18 cm from blade tip to the end of the ring; blade 14 -> 6 mm wide; the
    finger ring is a 48 x 28 mm frame of 6 mm bars (the place to pull on).
    """
    s = side
    out = cylinder((0.0, 0.0, (z0 + z1) / 2), 0.009, (z1 - z0) / 2)
    out += bar((0.006, s * 0.002), (0.050, s * 0.003), 0.014, z0, z1)  # blade root
    out += bar((0.050, s * 0.003), (0.088, s * 0.001), 0.007, z0, z1)  # blade tip
    out += bar((-0.006, -s * 0.003), (-0.040, -s * 0.012), 0.009, z0, z1)  # handle neck
    cx, cy, hx, hy, w = -0.066, -s * 0.020, 0.026, 0.014, 0.006
    out += box((cx - hx, cy - hy, z0), (cx + hx, cy - hy + w, z1))  # ring, side near -y
    out += box((cx - hx, cy + hy - w, z0), (cx + hx, cy + hy, z1))  # ring, side near +y
    out += box((cx - hx, cy - hy + w, z0), (cx - hx + w, cy + hy - w, z1))  # ring, far end
    out += box((cx + hx - w, cy - hy + w, z0), (cx + hx, cy + hy - w, z1))  # ring, near end
    return out


#: Barrett hand layout (metres, object frame): palm a cylinder on the table, the fixed finger
#: (F3) at -x, the two spreading fingers (F1 at +y, F2 at -y) at +x, all curling inwards.
BARRETT_PALM_RADIUS = 0.055
BARRETT_PALM_TOP = 0.075
BARRETT_FINGER_BASES = {"f3": (-0.032, 0.0), "f1": (0.026, 0.026), "f2": (0.026, -0.026)}


def barrett_finger(base_x: float, base_y: float, inward: float) -> list[Patch]:
    """One finger standing on the palm at (base_x, base_y): a knuckle block, a 6 cm proximal
    link straight up and a 4 cm distal link bent over towards ``inward`` (+1: +x, -1: -x)."""
    t = BARRETT_PALM_TOP
    out = box((base_x - 0.013, base_y - 0.012, t), (base_x + 0.013, base_y + 0.012, t + 0.014),
              skip=("-z",))  # knuckle
    out += box((base_x - 0.009, base_y - 0.010, t + 0.014), (base_x + 0.009, base_y + 0.010,
                                                             t + 0.074))  # proximal
    x_in = base_x + inward * 0.009
    x_tip = base_x + inward * 0.047
    out += box((min(x_in, x_tip), base_y - 0.009, t + 0.060),
               (max(x_in, x_tip), base_y + 0.009, t + 0.074))  # distal, bent over
    return out


def barrett_palm() -> list[Patch]:
    """Palm (cylinder 11 cm across, 7.5 cm high) with the fixed finger F3 on top."""
    out = cylinder((0.0, 0.0, BARRETT_PALM_TOP / 2 + 0.00025), BARRETT_PALM_RADIUS,
                   BARRETT_PALM_TOP / 2 - 0.00025, caps=(False, True), pieces=2)
    x, y = BARRETT_FINGER_BASES["f3"]
    return out + barrett_finger(x, y, +1.0)


def scraper_chassis() -> list[Patch]:
    """Chassis, cab and four wheels of a toy scraper (grader) truck, 25 x 17 x 17 cm, +x forward."""
    out = box((-0.13, -0.06, 0.04), (0.06, 0.06, 0.09))  # body
    out += box((-0.11, -0.05, 0.09), (-0.03, 0.05, 0.17))  # cab
    out += box((-0.02, -0.03, 0.09), (0.02, 0.03, 0.094))  # boom mount plate
    for x in (-0.09, 0.025):
        for y in (0.072, -0.072):
            out += cylinder((x, y, 0.0355), 0.035, 0.012, axis="y")
    return out


def scraper_boom() -> list[Patch]:
    """Boom: a 3 x 2 cm beam from its pivot on the chassis to 16 cm forward."""
    return box((-0.012, -0.015, 0.094), (0.168, 0.015, 0.114))


def scraper_blade() -> list[Patch]:
    """Blade (18 x 9 cm, 8 mm thick) hanging from a bracket at the boom's front end."""
    out = box((0.168, -0.02, 0.090), (0.180, 0.02, 0.118))  # bracket around the pivot
    out += box((0.180, -0.09, 0.014), (0.188, 0.09, 0.118))  # blade plate
    return out


#: Hinged cabinet (metres, object frame): 24 deep, 30 wide, 32 high, front at +x, a door over
#: the lower compartment (hinge on the front's -y edge) and a drawer above the shelf.
HCAB_X, HCAB_Y, HCAB_H, HCAB_T, HCAB_SHELF = 0.12, 0.15, 0.32, 0.012, 0.20


def hinged_cabinet() -> list[Patch]:
    """Carcass of the hinged cabinet: 12 mm panels, a shelf between door and drawer."""
    x0, x1, y, h, t, sh = -HCAB_X, HCAB_X, HCAB_Y, HCAB_H, HCAB_T, HCAB_SHELF
    z0 = 0.0005
    out = box((x0, -y, z0), (x1, y, z0 + t), skip=("-z",))  # bottom
    out += box((x0, -y, h - t), (x1, y, h))  # top
    out += box((x0, -y, z0 + t), (x1, -y + t, h - t))  # right side
    out += box((x0, y - t, z0 + t), (x1, y, h - t))  # left side
    out += box((x0, -y + t, z0 + t), (x0 + t, y - t, h - t))  # back
    out += box((x0 + t, -y + t, sh), (x1, y - t, sh + t))  # shelf
    return out


def hinged_cabinet_door() -> list[Patch]:
    """Door of the lower compartment (27.4 x 18.6 cm) with a vertical bar handle at its free
    edge (+y), closed."""
    x1, y, t = HCAB_X, HCAB_Y - HCAB_T - 0.001, HCAB_T
    out = box((x1 - t, -y, 0.0135), (x1, y, HCAB_SHELF - 0.001))  # panel
    for z in (0.07, 0.14):
        out += box((x1, 0.100, z - 0.006), (x1 + 0.016, 0.112, z + 0.006))  # handle posts
    out += box((x1 + 0.016, 0.098, 0.055), (x1 + 0.028, 0.114, 0.155))  # handle bar
    return out


def hinged_cabinet_drawer() -> list[Patch]:
    """Drawer above the shelf (front 27.4 x 9.4 cm, tray 20.8 cm deep), bar handle, closed."""
    x1, y, t = HCAB_X, HCAB_Y - HCAB_T - 0.001, HCAB_T
    z0, z1 = HCAB_SHELF + t + 0.001, HCAB_H - t - 0.001
    out = box((x1 - t, -y, z0), (x1, y, z1))  # front
    out += box((-0.10, -0.13, z0 + 0.001), (x1 - t, 0.13, z0 + 0.007))  # tray bottom
    out += box((-0.10, -0.13, z0 + 0.007), (x1 - t, -0.124, z1 - 0.02))  # tray right
    out += box((-0.10, 0.124, z0 + 0.007), (x1 - t, 0.13, z1 - 0.02))  # tray left
    out += box((-0.10, -0.124, z0 + 0.007), (-0.094, 0.124, z1 - 0.02))  # tray back
    zc = (z0 + z1) / 2
    for yy in (-0.05, 0.05):
        out += box((x1, yy - 0.006, zc - 0.006), (x1 + 0.02, yy + 0.006, zc + 0.006))  # posts
    out += box((x1 + 0.02, -0.06, zc - 0.008), (x1 + 0.032, 0.06, zc + 0.008))  # handle bar
    return out


PARTS = (
    Part("pliers_fixed", lambda: pliers_half(-1.0, 0.0005, 0.0085), 256, 256, 0.0005),
    Part("pliers_moving", lambda: pliers_half(+1.0, 0.0095, 0.0175), 256, 256, 0.0005),
    Part("truck_chassis", truck_chassis, 768, 768, 0.0008),
    Part("truck_bed", truck_bed, 512, 512, 0.0008),
    Part("cabinet", cabinet, 1024, 1024, 0.0012),
    Part("drawer", drawer, 768, 512, 0.0010),
    Part("table", table, 1024, 1024, 0.0009, saturation=0.4),
    Part("floor", floor, 768, 768, 0.004, density=0.7, saturation=0.5),
    Part("walls", walls, 1024, 1024, 0.006, density=0.7, saturation=0.5),
    Part("scissors_fixed", lambda: scissors_half(-1.0, 0.0005, 0.0045), 256, 256, 0.0005),
    Part("scissors_moving", lambda: scissors_half(+1.0, 0.0050, 0.0090), 256, 256, 0.0005),
    Part("barrett_palm", barrett_palm, 512, 512, 0.0008),
    Part("barrett_finger1", lambda: barrett_finger(*BARRETT_FINGER_BASES["f1"], -1.0),
         256, 256, 0.0007),
    Part("barrett_finger2", lambda: barrett_finger(*BARRETT_FINGER_BASES["f2"], -1.0),
         256, 256, 0.0007),
    Part("scraper_chassis", scraper_chassis, 768, 768, 0.0008),
    Part("scraper_boom", scraper_boom, 256, 512, 0.0008),
    Part("scraper_blade", scraper_blade, 512, 256, 0.0008),
    Part("hinged_cabinet", hinged_cabinet, 1024, 1024, 0.0012),
    Part("hinged_cabinet_door", hinged_cabinet_door, 512, 512, 0.0010),
    Part("hinged_cabinet_drawer", hinged_cabinet_drawer, 768, 512, 0.0010),
)


def generate(out_dir: Path, seed: int = SEED) -> dict[str, float]:
    """Write every part's OBJ and PNG into ``out_dir``; returns the texel size (m) per part."""
    return generate_parts(PARTS, out_dir, seed, generator="scenes/make_assets.py")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=HERE / "assets", help="output folder")
    parser.add_argument("--seed", type=int, default=SEED, help="master seed")
    args = parser.parse_args()
    texels = generate(args.out, args.seed)
    total = 0
    for part in PARTS:
        size = sum((args.out / f"{part.name}.{ext}").stat().st_size for ext in ("obj", "png"))
        total += size
        print(f"{part.name:15s} atlas {part.width}x{part.height}  "
              f"texel {texels[part.name] * 1000:5.2f} mm  {size / 1e6:5.2f} MB")
    print(f"total {total / 1e6:.2f} MB in {args.out}")


if __name__ == "__main__":
    main()
