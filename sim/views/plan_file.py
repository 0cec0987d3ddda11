"""A view plan as JSON, every number exact: the plan cache (:mod:`sim.capture.plan`) stores it."""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from sim.views.records import Ring, View, ViewPlan

#: Format tag of a view plan written by :func:`plan_to_json`.
PLAN_FORMAT = "artrecon-view-plan/1"


def _floats(a) -> list:
    """A float array as nested lists of Python floats (JSON writes them with ``repr``, which
    reads back to the same double: a plan from a file is bit for bit the plan that was solved)."""
    return np.asarray(a, dtype=float).tolist()


def plan_to_json(plan: ViewPlan) -> dict:
    """``plan`` as a JSON-serialisable dict that :func:`plan_from_json` reads back exactly."""
    return {
        "format": PLAN_FORMAT,
        "centre": _floats(plan.centre), "radius": float(plan.radius), "survey": plan.survey,
        "rings": [{f.name: getattr(r, f.name) for f in fields(Ring)} for r in plan.rings],
        "views": [{"index": v.index, "ring": v.ring, "azimuth": float(v.azimuth),
                   "elevation": float(v.elevation), "distance": float(v.distance),
                   "T_world_camera": _floats(v.T_world_camera),
                   "q": None if v.q is None else _floats(v.q),
                   "roll_deg": float(v.roll_deg), "reason": v.reason} for v in plan.views],
    }


def plan_from_json(obj: dict) -> ViewPlan:
    """The :class:`ViewPlan` of a dict written by :func:`plan_to_json`.

    Raises
    ------
    ValueError
        ``obj`` is not a plan of this format.
    """
    if not isinstance(obj, dict) or obj.get("format") != PLAN_FORMAT:
        raise ValueError(f"not a view plan of format {PLAN_FORMAT!r}")
    views = []
    for v in obj["views"]:
        views.append(View(index=int(v["index"]), ring=int(v["ring"]), azimuth=v["azimuth"],
                          elevation=v["elevation"], distance=v["distance"],
                          T_world_camera=np.array(v["T_world_camera"], dtype=float),
                          q=None if v["q"] is None else np.array(v["q"], dtype=float),
                          roll_deg=v["roll_deg"], reason=v["reason"]))
    return ViewPlan(centre=np.array(obj["centre"], dtype=float), radius=obj["radius"],
                    rings=[Ring(**r) for r in obj["rings"]], views=views,
                    survey=obj.get("survey"))
