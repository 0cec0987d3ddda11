"""Where scenes are and how a scene file compiles: the bundled scenes and stages, scene names and
paths, and MuJoCo's compile errors turned into messages that say what to do."""

from __future__ import annotations

import os
from pathlib import Path

import mujoco

from sim.scene.records import SceneError

#: Folder of the scenes that come with the harness (the stage, its assets, the bundled scenes).
BUNDLED_SCENES_DIR = Path(__file__).resolve().parents[2] / "scenes"
#: Folder of the scenes found by name; ``ARTRECON_SCENES_DIR`` points elsewhere (a folder laid
#: out the same way: scene files beside ``stage.xml``).
SCENES_DIR = Path(os.environ.get("ARTRECON_SCENES_DIR", BUNDLED_SCENES_DIR))

#: The stage file of each arm (``<custom><text name="artrecon:arm">``): the floor, walls, table,
#: lights and the arm on its rail, included by every scene that the arm works in.
STAGE_FILES = {"puma560": "stage.xml", "panda": "stage_panda.xml"}
#: Files in the scenes folder that are not scenes themselves: the stages, included by scenes.
NON_SCENE_FILES = frozenset(STAGE_FILES.values())


def list_scenes(folder: str | os.PathLike | None = None) -> list[str]:
    """Names of the scenes in ``folder`` (default :data:`SCENES_DIR`), sorted."""
    folder = Path(folder) if folder is not None else SCENES_DIR
    return sorted(p.stem for p in folder.glob("*.xml") if p.name not in NON_SCENE_FILES)


def scene_path(name_or_path: str | os.PathLike) -> Path:
    """Absolute path of a bundled scene name (``"pliers"``) or of an MJCF file path."""
    text = os.fspath(name_or_path)
    looks_like_path = (isinstance(name_or_path, os.PathLike) or text.endswith(".xml")
                       or os.sep in text or (os.altsep is not None and os.altsep in text))
    if looks_like_path:
        path = Path(text).expanduser().resolve()
        if not path.is_file():
            raise SceneError(f"{path}: no such scene file; give an existing MJCF file or one of "
                             f"the bundled scenes {list_scenes()}")
        return path
    path = (SCENES_DIR / f"{text}.xml").resolve()
    if text in {Path(f).stem for f in NON_SCENE_FILES} or not path.is_file():
        raise SceneError(f"no bundled scene named {text!r} in {SCENES_DIR}; the scenes are "
                         f"{list_scenes()} (or give the path of an MJCF file)")
    return path


def stage_file(arm: str = "puma560") -> Path:
    """Absolute path of the bundled stage that carries ``arm`` (a key of :data:`STAGE_FILES`).

    A scene anywhere on disk includes it by this path (``<include file="..."/>``): MuJoCo finds
    a file that an included file names relative to the scene's folder first and then relative
    to the included file's own folder, so the stage's assets and arm come from the harness and
    the scene's folder holds only the scene and its own assets.
    """
    if arm not in STAGE_FILES:
        raise ValueError(f"unknown arm {arm!r}; the stages carry {sorted(STAGE_FILES)}")
    return BUNDLED_SCENES_DIR / STAGE_FILES[arm]


def _missing_file_fix(path: Path, msg: str) -> str:
    """The fix for a file MuJoCo could not open while compiling the scene ``path``."""
    stages = sorted(STAGE_FILES.values())
    if any(f"'{name}'" in msg or f"/{name}'" in msg for name in stages) \
            and not (path.parent / "stage.xml").is_file():
        return ("the scene includes a stage that is not beside it; make its folder "
                "self-contained as `python -m sim.author import` writes scenes (a copy of the "
                "stage, its assets and the arm beside the scene: sim.author.stage.stage_copy), "
                f"or, for this clone only, include the bundled one by its absolute path, "
                f"<include file=\"{stage_file()}\"/> (or {stage_file('panda')} for the Panda)")
    if "robots" in msg:
        return ("MuJoCo 4.0 looks for the stage's arm (<model file=\"../robots/...\">) from the "
                "working directory first and, for a stage included from another folder, "
                "misplaces it when the working directory has a ../robots beside it; run from "
                "the repository root (or any folder without ../robots)")
    return (f"file= paths are relative to the scene file's folder {path.parent}, then to the "
            f"folder of the included file that names them; for the bundled assets run "
            f"`python scenes/make_assets.py`")


def compile_scene(path: Path) -> mujoco.MjModel:
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        msg = str(err).strip()
        if "opening file" in msg or "resource not found" in msg or "could not open" in msg:
            fix = _missing_file_fix(path, msg)
        else:
            fix = "fix the element MuJoCo names (see scenes/README.md for the conventions)"
        raise SceneError(f"{path}: MuJoCo could not compile the scene: {msg}. Fix: {fix}") \
            from err
