"""``python -m sim.author import PATH --out DIR``: import an articulated object as a scene."""

from __future__ import annotations

import argparse
import logging
import math
import re
import sys
from pathlib import Path

from sim.author.build import import_object
from sim.author.config import UP_AXES, ImportConfig
from sim.author.source import AuthorError
from sim.scene import load_scene
from sim.texture_check import TextureError, check_texture

#: Units a joint value may carry on the command line, to radians or metres.
UNITS = {"": 1.0, "rad": 1.0, "deg": math.pi / 180, "m": 1.0, "cm": 0.01, "mm": 0.001}


def joint_value(text: str) -> tuple[str, float]:
    """``JOINT=VALUE[unit]`` (unit rad, deg, m, cm or mm; none: radians or metres)."""
    m = re.fullmatch(r"\s*([^=\s]+)\s*=\s*([-+0-9.eE]+)\s*([a-z]*)\s*", text)
    if not m or m.group(3) not in UNITS:
        raise argparse.ArgumentTypeError(
            f"expected JOINT=VALUE with an optional unit ({', '.join(u for u in UNITS if u)}), "
            f"e.g. lid=30deg or drawer=0.1, got {text!r}")
    try:
        value = float(m.group(2))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"{text!r}: {m.group(2)!r} is not a number") from err
    return m.group(1), value * UNITS[m.group(3)]


def parser() -> argparse.ArgumentParser:
    default = ImportConfig()
    p = argparse.ArgumentParser(prog="python -m sim.author",
                                description="Author scenes for the harness.")
    sub = p.add_subparsers(dest="command", required=True)
    imp = sub.add_parser(
        "import", help="import an articulated object from a URDF or an MJCF file",
        description="Import an articulated object (URDF, e.g. PartNet-Mobility's mobility.urdf, "
                    "or MJCF) as a scene: scaled onto the table centre, joints converted, "
                    "every part textured, configurations A and B chosen, the scene validated "
                    "and checked to hold; then the texture check.")
    imp.add_argument("path", type=Path, help="the URDF or MJCF file")
    imp.add_argument("--out", type=Path, required=True,
                     help="folder of the scene (NAME.xml and assets/NAME_*, with a copy of "
                          "the stage and the arm beside them: the folder holds everything)")
    imp.add_argument("--name", help="scene name (default: from the file, or the folder of a "
                                    "mobility.urdf)")
    size = imp.add_mutually_exclusive_group()
    size.add_argument("--size", type=float, default=default.size,
                      help=f"largest extent of the object at A, metres (default {default.size})")
    size.add_argument("--scale", type=float, help="a fixed scale factor instead (1 keeps a "
                                                  "metric source's size)")
    imp.add_argument("--up", choices=sorted(UP_AXES), default=default.up,
                     help="the source's up axis (default +z)")
    imp.add_argument("--body", help="MJCF: the object's root body (default: the only top-level "
                                    "body with geoms)")
    imp.add_argument("--config-a", type=joint_value, nargs="+", default=[], metavar="JOINT=VALUE",
                     help="joint values of configuration A (default: 0, or the limit nearest 0)")
    imp.add_argument("--config-b", type=joint_value, nargs="+", default=[], metavar="JOINT=VALUE",
                     help="joint values of configuration B, e.g. lid=30deg drawer=10cm (default: "
                          "every joint moves 30 deg or 10 cm inside its range)")
    imp.add_argument("--density", type=float, default=default.density,
                     help=f"kg/m^3 of the collision shapes (default {default.density:g})")
    imp.add_argument("--texel", type=float, default=default.texel,
                     help=f"texel size of the generated textures, m (default {default.texel:g})")
    imp.add_argument("--seed", type=int, default=default.seed, help="texture seed")
    imp.add_argument("--collision", choices=("box", "hull"), default=default.collision,
                     help="collision shape of each mesh: box (default; the oriented box around "
                          "it, where the arm's default grasp points lie) or hull (convex hull)")
    imp.add_argument("--texture", choices=("generated", "source"), default=default.texture,
                     help="generated (default): every part UV-unwrapped and given a new "
                          "non-repeating texture; source: keep the meshes' own UVs and images "
                          "(then the texture check judges whether they are rich enough)")
    imp.add_argument("--arm", choices=("puma560", "panda"), default=default.arm,
                     help="the arm on the stage (default puma560)")
    imp.add_argument("--overwrite", action="store_true",
                     help="replace the files of an earlier import of the same name")
    imp.add_argument("--no-texture-check", action="store_true",
                     help="skip the texture check of the written scene")
    imp.add_argument("-v", "--verbose", action="store_true", help="log what the import does")
    return p


def main(argv: list[str] | None = None) -> int:
    p = parser()
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        config = ImportConfig(name=args.name, size=args.size, scale=args.scale, up=args.up,
                              body=args.body, config_a=dict(args.config_a),
                              config_b=dict(args.config_b), density=args.density,
                              texel=args.texel, seed=args.seed, texture=args.texture,
                              collision=args.collision, arm=args.arm,
                              overwrite=args.overwrite)
    except ValueError as err:
        p.error(str(err))
    try:
        res = import_object(args.path, args.out, config)
    except AuthorError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {res.scene} and {len(res.assets)} files in {res.scene.parent / 'assets'} "
          f"(scale {res.scale:.4g})")
    if res.stage:
        print(f"with the stage beside it: {len(res.stage)} files (the stage, its assets, the "
              f"arm in robots/): a self-contained folder")
    for c, q in (("A", res.config_a), ("B", res.config_b)):
        print(f"configuration {c}: " + ", ".join(f"{k}={v:.4g}" for k, v in q.items()))
    for n in res.notes:
        print(f"  note: {n}")
    if not args.no_texture_check:
        try:
            report = check_texture(load_scene(res.scene))
        except TextureError as err:
            print(f"error: {err}", file=sys.stderr)
            return 1
        print(report.summary())
    print(f"next: python -m sim.evaluate {res.scene}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
