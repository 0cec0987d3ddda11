"""``python -m sim.evaluate``: capture, reconstruct, register, manipulate and score scenes.

Rooms: :mod:`~sim.evaluate.config` (EvalConfig), :mod:`~sim.evaluate.stages` (the cached stages),
:mod:`~sim.evaluate.runner` (one scene, a run), :mod:`~sim.evaluate.scoring` (ground truth, after
the fact), :mod:`~sim.evaluate.gates` (the one gate table and verdict),
:mod:`~sim.evaluate.report` (results.json, results.md, pictures), :mod:`~sim.evaluate.record`
(the typed record that is results.json's schema, with its ``schema_version``),
:mod:`~sim.evaluate.sweep` (many runs -- scenes x seeds x perturbations -- on worker processes or
Ray, merged), :mod:`~sim.evaluate.cli`.
"""

from sim.evaluate.cli import main
from sim.evaluate.config import STAGES, EvalConfig, StageError
from sim.evaluate.gates import GATES, verdict
from sim.evaluate.runner import evaluate_scene, run_meta
from sim.evaluate.scoring import (
    link_correspondence,
    rigid_bodies,
    sample_surface,
    score_joints,
    score_scene,
    segmentation_truth,
)
from sim.evaluate.sweep import run

__all__ = ["GATES", "STAGES", "EvalConfig", "StageError", "evaluate_scene", "link_correspondence",
           "main", "rigid_bodies", "run", "run_meta", "sample_surface",
           "score_joints", "score_scene", "segmentation_truth", "verdict"]
