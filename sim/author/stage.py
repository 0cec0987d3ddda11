"""The stage beside an imported scene: a scene folder that holds everything it needs.

A scene written by :func:`sim.author.import_object` outside ``scenes/`` gets its own copy of the
harness's stage (``stage.xml`` or ``stage_panda.xml``), the stage's assets
(``assets/floor.*``, ``walls.*``, ``table.*``) and the arm's MJCF with its meshes and licence
(``robots/<arm>/``), as a MuJoCo Menagerie model folder holds its own files: the folder opens in
``mujoco.MjModel.from_xml_path`` and in the harness from any working directory, moved or copied to
another place, clone or machine, and the evaluation's cache key (:func:`sim.cache.scene_hash`,
over the files relative to the scene's folder) is the same wherever the folder is.

One difference from the bundled stage: the arm's ``<model>`` asset is declared by the scene file,
not by the stage copy. MuJoCo 4.0 resolves a ``<model file=...>`` that an *included* file names
against the scene's folder twice when the scene is opened by a relative path
(``out/scene.xml`` looks for ``out/out/robots/...``); named by the scene file itself it is found.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from sim.author.source import AuthorError
from sim.cache import scene_files
from sim.scene import BUNDLED_SCENES_DIR, stage_file

#: The arms' folders of the harness (``robots/<arm>/``); bundled stages name them ``../robots``.
ROBOTS_DIR = BUNDLED_SCENES_DIR.resolve().parent / "robots"
#: Words in the first comment of a stage copy: an existing stage file without them was not
#: written by the import and is never replaced.
MARKER = "written by sim.author"
#: The bundled stage's arm: ``<model name="..." file="../robots/..."/>`` on a line of its own.
_MODEL = re.compile(r'^([ \t]*)<model\s+name="([^"]+)"\s+file="\.\./robots/([^"]+)"\s*/>[ \t]*$',
                    re.M)
#: Files of an arm's folder that travel with its MJCF although MuJoCo does not read them.
_KEEP = ("LICENSE", "README.md")


@dataclass(frozen=True)
class StageCopy:
    """The stage of one arm, as files of a scene folder."""

    name: str
    """file name of the stage (``stage.xml``, ``stage_panda.xml``)"""
    head: list[str]
    """the scene file's first lines inside ``<mujoco>``: the arm's ``<model>`` and the include"""
    files: dict[str, bytes]
    """contents by path relative to the scene folder: the stage copy, its assets, the arm"""


def stage_copy(arm: str) -> StageCopy:
    """The bundled stage carrying ``arm``, its assets and the arm, laid out for a scene folder.

    Raises
    ------
    AuthorError
        The bundled stage is not laid out as expected (a bug of the harness: report it).
    """
    src = stage_file(arm).resolve()
    text = src.read_text()
    models = _MODEL.findall(text)
    if len(models) != 1:
        raise AuthorError(f"{src}: expected one <model name=... file=\"../robots/...\"/> line "
                          f"(the arm), found {len(models)}; the stage cannot be copied beside "
                          f"an imported scene (report this bug)")
    indent, model, robot_file = models[0]
    model_line = f'<model name="{model}" file="robots/{robot_file}"/>'
    copy = _MODEL.sub(f"{indent}<!-- the arm, {model_line}, is declared by each scene file -->",
                      text, count=1)
    copy = (f"<!-- A copy of the harness's scenes/{src.name}, {MARKER}: this folder holds "
            f"everything\n     its scenes need (this file, assets/, robots/). One change: the "
            f"arm's <model> asset\n     is declared by each scene file, because MuJoCo 4.0 "
            f"misplaces a <model file=...> named\n     by an included file when the scene is "
            f"opened by a relative path. -->\n" + copy)
    files = {src.name: copy.encode()}
    robot_dirs = set()
    for f in scene_files(src):
        if f == src:
            continue
        if not f.is_file():
            raise AuthorError(f"{src}: names {f}, which does not exist; for the bundled assets "
                              f"run `python scenes/make_assets.py`")
        if f.is_relative_to(BUNDLED_SCENES_DIR.resolve()):
            rel = f.relative_to(BUNDLED_SCENES_DIR.resolve())
        elif f.is_relative_to(ROBOTS_DIR):
            rel = Path("robots") / f.relative_to(ROBOTS_DIR)
            robot_dirs.add(ROBOTS_DIR / rel.parts[1])
        else:
            raise AuthorError(f"{src}: names {f}, outside scenes/ and robots/; the stage cannot "
                              f"be copied beside an imported scene (report this bug)")
        files[rel.as_posix()] = f.read_bytes()
    for d in sorted(robot_dirs):
        for f in sorted(p for p in d.rglob("*") if p.is_file() and p.name in _KEEP):
            files[(Path("robots") / f.relative_to(ROBOTS_DIR)).as_posix()] = f.read_bytes()
    arm_dir = f"robots/{Path(robot_file).parts[0]}/"
    head = [f"  <!-- The stage ({src.name}) and its arm ({arm_dir}): files of this folder. -->",
            "  <asset>", f"    {model_line}", "  </asset>", f'  <include file="{src.name}"/>']
    return StageCopy(src.name, head, files)


def is_stage_copy(path: Path) -> bool:
    """Whether an existing stage file was written by the import (may be replaced on
    ``--overwrite``)."""
    try:
        return MARKER in path.read_text(errors="replace")[:400]
    except OSError:
        return False
