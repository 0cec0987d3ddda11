"""Bring your own object: import an articulated model from a URDF or an MJCF as a scene.

``python -m sim.author import PATH --out DIR`` (or :func:`import_object`) reads a URDF
(PartNet-Mobility's ``mobility.urdf`` with OBJ meshes per part, or any URDF) or an MJCF file and
writes ``DIR/NAME.xml`` with ``DIR/assets/NAME_*``: a scene of this harness that
``python -m sim.evaluate DIR/NAME.xml`` captures, reconstructs, manipulates and scores. The folder
is self-contained: a copy of the stage, its assets and the arm lie beside the scene
(:mod:`sim.author.stage`), so it opens in MuJoCo and in the harness wherever it is moved. See
:mod:`sim.author.build` for what the import does and ``scenes/README.md`` ("Importing an
object") for a walk-through.
"""

from sim.author.build import ImportResult, import_object
from sim.author.config import ImportConfig
from sim.author.source import AuthorError

__all__ = ["AuthorError", "ImportConfig", "ImportResult", "import_object"]
