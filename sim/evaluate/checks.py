"""What ``python -m sim.evaluate`` checks before any capture: every named scene loads and has a
joint that moves between its two configurations, and ``--out`` neither is a file nor lies on or
around a scene's files. A run that cannot give a result is refused in a second, not after the
captures."""

from __future__ import annotations

from pathlib import Path

from artrecon.errors import InputError
from artrecon.files import check_output_path
from sim.cache import scene_files
from sim.scene import Scene, SceneError, load_scene

__all__ = ["check_scene", "check_run"]


def check_scene(scene: Scene) -> Scene:
    """``scene`` if its object has a joint that moves between configuration A and B.

    Raises
    ------
    SceneError
        No object joint (one rigid link), or no joint whose config_a and config_b differ:
        nothing to reconstruct, and nothing for the arm to move.
    """
    if not scene.joints:
        raise SceneError(
            f"{scene.path}: the object has no joints (one rigid link): there is nothing to "
            "reconstruct as an articulated model and nothing for the arm to move. Fix: give a "
            'moving part a <joint type="hinge"> or <joint type="slide"> with a range and its '
            "config_a / config_b values (scenes/README.md), or choose another scene")
    if not scene.moving_joints:
        names = ", ".join(j.name for j in scene.joints)
        raise SceneError(
            f"{scene.path}: no joint moves between the two configurations (config_a and config_b "
            f"are equal for {names}): nothing moved, so no joint can be observed. Fix: give a "
            "joint different config_a and config_b values")
    return scene


def check_run(names: list[str], out: str | Path) -> list[Scene]:
    """Load and check every scene (:func:`check_scene`) and the report folder.

    Returns
    -------
    list of Scene
        The loaded scenes, in order.

    Raises
    ------
    SceneError
        A scene does not load or has no moving joint.
    InputError
        ``out`` is a file, or is, contains or lies inside one of the scenes' files.
    """
    scenes = [check_scene(load_scene(name)) for name in names]
    inputs = []
    for scene in scenes:
        inputs += [scene.path] + [f for f in scene_files(scene.path) if f != scene.path]
    out = Path(out)
    check_output_path(out, inputs, example="runs/eval")
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out} is a file, not a folder; the report folder holds "
                         "results.json, results.md, pictures and cache/: name a folder")
    return scenes
