"""Comparing two registrations, and applying one to a model."""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from artrecon.confidence import rescale_confidence
from artrecon.geometry import rotation_angle
from artrecon.model import ArticulatedModel
from artrecon.procrustes import Similarity
from artrecon.refine import map_record
from artrecon.register._checks import _points


@dataclass(frozen=True)
class RegistrationComparison:
    """Disagreement of two model-to-robot similarities (see :func:`compare_registrations`)."""

    translation_mm: float
    """RMS distance (mm) between the two images of the model points"""
    max_translation_mm: float
    """largest such distance (mm)"""
    rotation_deg: float
    """angle of the relative rotation (deg)"""
    scale_ratio: float
    """scale of the first over scale of the second"""

    def to_dict(self) -> dict:
        return {k: float(v) for k, v in self.__dict__.items()}


def compare_registrations(T1: Similarity, T2: Similarity, points) -> RegistrationComparison:
    """How far apart two registrations put the model.

    Parameters
    ----------
    T1, T2 : Similarity
        Two estimates of ``T_robot_model``.
    points : (n, 3) float
        Model points (model frame) at which the translation difference is measured (the object's
        points: where the arm will grasp).
    """
    p = _points("points", points)
    d = np.linalg.norm(T1.apply(p) - T2.apply(p), axis=1) * 1e3
    return RegistrationComparison(float(np.sqrt(np.mean(d ** 2))), float(d.max()),
                                  float(np.rad2deg(rotation_angle(T1.rotation.T @ T2.rotation))),
                                  float(T1.scale / T2.scale))


def apply_registration(model: ArticulatedModel, T_robot_model: Similarity) -> ArticulatedModel:
    """A copy of ``model`` in the robot frame, in metres.

    Points are mapped by the similarity, normals and axis directions rotated, axis points mapped,
    prismatic joint states and residuals scaled to metres (revolute states are angles and stay);
    each link's A-to-B transform and each joint's relative transform are conjugated into the robot
    frame. The result has ``scale = 1.0`` (metres per unit) and ``scale_known = True``;
    ``frames["T_robot_sfm"]`` holds the similarity's (4, 4) matrix, which maps the input model's
    frame (scaled) to the robot frame. Named frames of the input that map *from* the model frame
    (``T_x_model``) are re-expressed so they map from the new frame.

    Parameters
    ----------
    model : ArticulatedModel
        In its SfM frame (``scale`` may already be set: it is ignored; the similarity's scale is
        the one used).
    T_robot_model : Similarity

    Returns
    -------
    ArticulatedModel
    """
    if not isinstance(T_robot_model, Similarity):
        raise TypeError(f"T_robot_model must be an artrecon Similarity, got "
                        f"{type(T_robot_model).__name__}")
    T = T_robot_model
    T_inv = T.inverse()
    s, R = T.scale, T.rotation
    out = copy.deepcopy(model)
    for lk in out.links:
        lk.points = T.apply(lk.points) if len(lk.points) else lk.points.copy()
        if lk.normals is not None and len(lk.normals):
            lk.normals = lk.normals @ R.T
        lk.transform_a_to_b = T @ lk.transform_a_to_b @ T_inv
    for j in out.joints:
        j.axis_direction = R @ j.axis_direction
        j.axis_point = T.apply(j.axis_point)
        if j.type == "prismatic":
            j.state_a *= s
            j.state_b *= s
        j.residual *= s
        j.confidence = rescale_confidence(j.confidence, s)  # its lengths to metres
        if "refinement" in j.confidence:  # its axes and lengths too (artrecon.refine)
            j.confidence["refinement"] = map_record(j.confidence["refinement"], T, j.type)
        j.relative_transform = T @ j.relative_transform @ T_inv
    frames = {}
    for name, M in model.frames.items():
        frames[name] = M @ T_inv.matrix if name.endswith("_model") else M.copy()
    frames["T_robot_sfm"] = T.matrix
    out.frames = frames
    out.scale = 1.0
    out.scale_known = True
    out.metadata = dict(out.metadata)
    out.metadata["registration"] = {"frame": "robot", "units": "m",
                                    "scale_m_per_sfm_unit": s,
                                    "T_robot_sfm": T.to_dict()}
    return out
