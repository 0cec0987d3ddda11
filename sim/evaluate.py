"""``python -m sim.evaluate``: the harness's main job.

For now (until the evaluation pipeline lands) it validates scenes and prints their ground truth:
each scene is compiled and checked by :func:`sim.scene.load_scene`, then stepped for a second of
physics, which must raise no MuJoCo warning. The exit status is non-zero if any scene is bad.

Usage::

    python -m sim.evaluate                 # every bundled scene
    python -m sim.evaluate pliers my.xml   # bundled names or MJCF paths
"""

from __future__ import annotations

import argparse
import logging
import sys

import numpy as np

from sim.scene import Scene, SceneError, list_scenes, load_scene, physics_warnings

log = logging.getLogger(__name__)

#: Simulated time stepped per scene to look for MuJoCo warnings (the Menagerie check).
CHECK_SECONDS = 1.0


def _fmt(v: np.ndarray, digits: int = 3) -> str:
    return "(" + ", ".join(f"{x:+.{digits}f}" for x in v) + ")"


def ground_truth_rows(scene: Scene) -> list[list[str]]:
    """Table rows (one per joint) of a scene's ground truth, human units (deg, mm)."""
    rows = []
    for j in scene.joints:
        unit, scale = ("deg", np.rad2deg(1.0)) if j.type == "revolute" else ("mm", 1000.0)
        rows.append([
            scene.name, j.name, j.type, f"{j.parent} -> {j.child}", _fmt(j.axis),
            _fmt(j.point), f"{j.value_a * scale:.1f} {unit}", f"{j.value_b * scale:.1f} {unit}",
            f"{j.motion * scale:+.1f} {unit}",
            f"[{j.range[0] * scale:.1f}, {j.range[1] * scale:.1f}] {unit}"])
    if not rows:
        rows.append([scene.name, "-", "rigid", "object", "-", "-", "-", "-", "-", "-"])
    return rows


def format_table(rows: list[list[str]]) -> str:
    """A plain-text table with a header."""
    header = ["scene", "joint", "type", "parent -> child", "axis (world, at A)",
              "point on axis (m)", "A", "B", "B - A", "range"]
    table = [header, *rows]
    widths = [max(len(r[i]) for r in table) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
             for r in table]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m sim.evaluate",
        description="Validate scenes (compile, conventions, 1 s of physics without MuJoCo "
                    "warnings) and print their ground truth.")
    parser.add_argument("scenes", nargs="*",
                        help=f"bundled scene names or MJCF paths (default: all of "
                             f"{list_scenes()})")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")

    names = args.scenes or list_scenes()
    rows, bad = [], []
    for name in names:
        try:
            scene = load_scene(name)
            warnings = physics_warnings(scene, CHECK_SECONDS)
            if warnings:
                raise SceneError(f"{scene.path}: MuJoCo warnings in {CHECK_SECONDS:g} s of "
                                 f"physics: {warnings}; fix: look for interpenetrating "
                                 f"collision geoms, bad inertias or unstable gains")
        except SceneError as err:
            bad.append(name)
            print(f"BAD  {name}: {err}", file=sys.stderr)
            continue
        print(f"ok   {scene.name}: {len(scene.links)} links "
              f"({', '.join(li.name for li in scene.links)}), {len(scene.joints)} joints, "
              f"{scene.model.nbody} bodies, {scene.model.ngeom} geoms, no warnings in "
              f"{CHECK_SECONDS:g} s")
        rows += ground_truth_rows(scene)
    if rows:
        print()
        print(format_table(rows))
    if bad:
        print(f"\n{len(bad)} of {len(names)} scenes are bad: {', '.join(bad)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
