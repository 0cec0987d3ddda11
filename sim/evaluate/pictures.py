"""The report's pictures, drawn with OpenCV (matplotlib is not a dependency).

- ``<scene>_reconstruction.png``: the registered model's points projected into a captured image of
  configuration A (true camera pose), coloured by the model's link, with the estimated joint axes
  in red and the true ones in green, like the method's figures;
- ``<scene>_errors.png``: a bar per figure, as a fraction of its gate (the line at 1.0): green
  bars pass, red bars fail, the value written beside each;
- a sweep's ``sweep_errors.png`` (the gated errors of every run per scene and seed) and
  ``sweep_<perturbation>.png`` (errors against each perturbation's strength, the gate drawn).

Every file is written whole or not at all (:mod:`artrecon.files`). The charts read the typed
record (:mod:`sim.evaluate.record`): a scene's :class:`~sim.evaluate.record.SceneRecord`, a
sweep's :class:`~sim.evaluate.record.Results`.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from artrecon.files import write_bytes_atomic
from sim.evaluate import record
from sim.evaluate.gates import GATES
from sim.evaluate.report import jsonable_scene
from sim.scene import load_scene

log = logging.getLogger(__name__)


#: Link colours (RGB), cycled; link 0 (usually the base) grey-blue.
PALETTE = [(90, 140, 230), (250, 180, 40), (170, 90, 220), (40, 200, 200), (240, 110, 160),
           (140, 200, 60), (200, 120, 60), (120, 120, 120)]
RED = (230, 30, 30)
GREEN = (30, 200, 60)
#: Elevation (deg) of the captured view preferred for the overview picture: high enough to see
#: the object's top and its joint, low enough to see its sides.
OVERVIEW_ELEVATION_DEG = 40.0


def project(points: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (n, 2) and depths (n,) of world points in an OpenCV camera."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    T = np.asarray(T_world_camera, dtype=float)
    Xc = (P - T[:3, 3]) @ T[:3, :3]
    z = Xc[:, 2]
    uv = (Xc @ np.asarray(K, float).T)[:, :2] / np.where(np.abs(z) > 1e-9, z, 1e-9)[:, None]
    return uv, z


def draw_reconstruction(image: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray,
                        points: np.ndarray, labels: np.ndarray,
                        axes: list[tuple[np.ndarray, np.ndarray, tuple[int, int, int]]],
                        axis_length: float = 0.25, title: str = "") -> np.ndarray:
    """Points coloured by link over a darkened image, and axis segments.

    Parameters
    ----------
    image : (h, w, 3) uint8 RGB
    K : (3, 3) float
    T_world_camera : (4, 4) float
    points : (n, 3) float
        World points.
    labels : (n,) int
        Link index of each point (colour).
    axes : list of (centre (3,), direction (3,), RGB colour)
        Segments of ``axis_length`` (m) centred on ``centre``.
    title : str

    Returns
    -------
    picture : (h, w, 3) uint8 RGB
    """
    img = (np.asarray(image, dtype=np.float32)[:, :, :3] * 0.45).astype(np.uint8)
    h, w = img.shape[:2]
    uv, z = project(points, K, T_world_camera)
    order = np.argsort(-z)  # far first, near drawn over them
    ok = (z[order] > 0)
    u = np.round(uv[order, 0]).astype(int)
    v = np.round(uv[order, 1]).astype(int)
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    lab = np.asarray(labels)[order]
    colours = np.array([PALETTE[k % len(PALETTE)] for k in range(max(1, lab.max() + 1))],
                       dtype=np.uint8)
    img[v[ok], u[ok]] = colours[lab[ok]]
    for centre, direction, colour in axes:
        d = np.asarray(direction, float) / np.linalg.norm(direction)
        ends = np.array([centre - 0.5 * axis_length * d, centre + 0.5 * axis_length * d])
        e_uv, e_z = project(ends, K, T_world_camera)
        if (e_z > 0).all():
            p0, p1 = (tuple(int(round(c)) for c in e) for e in e_uv)
            # true axes (drawn first) wider, so an estimate on top of them leaves them visible
            cv2.line(img, p0, p1, colour, 6 if colour == GREEN else 2, cv2.LINE_AA)
            cv2.circle(img, p1, 5, colour, -1, cv2.LINE_AA)
    if title:
        cv2.putText(img, title, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1,
                    cv2.LINE_AA)
    cv2.putText(img, "estimated axis", (10, h - 30), cv2.FONT_HERSHEY_SIMPLEX, 0.5, RED, 1,
                cv2.LINE_AA)
    cv2.putText(img, "true axis", (10, h - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.5, GREEN, 1,
                cv2.LINE_AA)
    return img


def error_bars(result: record.SceneRecord, gates: dict
               ) -> list[tuple[str, float | None, float, str]]:
    """(label, value, gate, unit) of a scene's gated figures; for accuracy-like figures
    (higher is better) the value is the shortfall ``1 - value`` against ``1 - gate``."""
    bars = []
    for j in result.joints or []:
        n = j.name
        bars.append((f"{n} axis angle", j.axis_angle_deg, gates["axis_angle_deg"], "deg"))
        if j.type_true == "revolute":
            bars.append((f"{n} axis position", j.axis_position_mm, gates["axis_position_mm"],
                         "mm"))
        unit = j.state_error_unit or "deg"
        bars.append((f"{n} state", j.state_error, gates[f"state_error_{unit}"], unit))
    seg = result.segmentation_accuracy
    bars.append(("segmentation miss", None if seg is None else 1.0 - seg,
                 1.0 - gates["segmentation_accuracy"], ""))
    bars.append(("points off the object", result.segmentation and
                 result.segmentation.off_surface_share, gates["off_object_share"], ""))
    bars.append(("manipulation rel. err", result.manipulation and
                 result.manipulation.relative_error, gates["manipulation_relative_error"], ""))
    return bars


def draw_error_chart(title: str, bars: list[tuple[str, float | None, float, str]],
                     width: int = 720) -> np.ndarray:
    """Horizontal bars of value/gate with the gate at 1.0 (RGB uint8 image)."""
    row, top, left, right = 34, 50, 230, 130
    h = top + row * len(bars) + 40
    img = np.full((h, width, 3), 255, np.uint8)
    cv2.putText(img, title, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.65, (0, 0, 0), 1, cv2.LINE_AA)
    span = width - left - right
    x_gate = left + span // 2  # value/gate = 1 at the middle; 2 (and beyond) at the end
    for i, (label, value, gate, unit) in enumerate(bars):
        y = top + i * row
        cv2.putText(img, label, (10, y + 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1,
                    cv2.LINE_AA)
        if value is None:
            cv2.putText(img, "n/a (missing)", (left + 5, y + 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                        RED, 1, cv2.LINE_AA)
            continue
        frac = value / gate if gate > 0 else 0.0
        x1 = left + int(min(frac, 2.0) / 2.0 * span)
        colour = GREEN if frac <= 1.0 else RED
        cv2.rectangle(img, (left, y + 6), (max(x1, left + 1), y + row - 6), colour, -1)
        text = f"{value:.3g} {unit} (gate {gate:.3g})"
        cv2.putText(img, text, (min(x1, left + span) + 6, y + 22), cv2.FONT_HERSHEY_SIMPLEX,
                    0.42, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.line(img, (x_gate, top - 4), (x_gate, top + row * len(bars)), (0, 0, 0), 1)
    cv2.putText(img, "gate", (x_gate - 16, top + row * len(bars) + 18),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def _write_png(path: Path, rgb: np.ndarray) -> None:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError(f"OpenCV could not encode {path}")
    write_bytes_atomic(path, buf.tobytes())


def write_scene_pictures(result: dict, out_dir: Path) -> list[Path]:
    """The two pictures of a scene (whatever its result allows: none if it failed early), from
    the runner's result (:func:`sim.evaluate.runner.evaluate_scene`: its figures, read as the
    record results.json will hold, and its in-memory model and points)."""
    out_dir = Path(out_dir)
    name = result["scene"]
    written = []
    if result.get("joints") or result.get("segmentation_accuracy") is not None:
        path = out_dir / f"{name}_errors.png"
        scene = record.SceneRecord.from_json(jsonable_scene(result), name)
        _write_png(path, draw_error_chart(f"{name}: errors as a fraction of their gates",
                                          error_bars(scene, GATES)))
        written.append(path)
    arrays = result.get("_arrays")
    if not arrays or "_set_a" not in result:
        return written
    set_a = Path(result["_set_a"])
    truth = json.loads((set_a / "ground_truth" / "poses.json").read_text())
    cams = json.loads((set_a / "cameras.json").read_text())
    view = min(truth["images"],
               key=lambda im: abs(im["view"]["elevation_deg"] - OVERVIEW_ELEVATION_DEG))
    image = np.asarray(Image.open(set_a / "images" / view["file"]).convert("RGB"))
    scene = load_scene(result.get("scene_file", name))
    registered = result["_registered"]
    samples, sample_link = arrays["_samples"], arrays["_sample_link"]
    centre = samples.mean(axis=0)
    size = float(np.linalg.norm(samples.max(0) - samples.min(0)))

    def foot(point, d):  # the axis point nearest the object's centre
        d = d / np.linalg.norm(d)
        return point + ((centre - point) @ d) * d

    axes = []
    for j in scene.moving_joints:
        child = [k for k, li in enumerate(scene.links) if li.name == j.child][0]
        c = samples[sample_link == child].mean(0) if j.type == "prismatic" else foot(j.point,
                                                                                    j.axis)
        axes.append((c, j.axis, GREEN))
    for j in registered.joints:
        pts = registered.links[j.child].points
        c = pts.mean(0) if j.type == "prismatic" and len(pts) else foot(j.axis_point,
                                                                      j.axis_direction)
        axes.append((c, j.axis_direction, RED))
    pic = draw_reconstruction(image, np.asarray(cams["K"], float),
                              np.asarray(view["T_world_camera"], float), arrays["_points"],
                              arrays["_point_labels"], axes, axis_length=0.8 * size,
                              title=f"{name}: registered model over view {view['file']}")
    path = out_dir / f"{name}_reconstruction.png"
    _write_png(path, pic)
    written.append(path)
    return written



#: Figure families of the sweep charts: (key, title); a run's value of a family is its worst
#: :func:`error_bars` bar of that family as a fraction of the gate (so joints in degrees and in
#: millimetres share one scale).
FAMILIES = (("axis angle", "axis angle"), ("axis position", "axis position"),
            ("state", "joint state"), ("segmentation miss", "segmentation miss (1-acc)"),
            ("points off the object", "points off the object"),
            ("manipulation rel. err", "manipulation relative error"))


def run_bars(result: record.SceneRecord | None, manipulate: bool = True
             ) -> list[tuple[str, float | None, float, str]]:
    """:func:`error_bars` of a run's result, lower is better for each (none for a run that has
    no result; no manipulation bar for a run that did not manipulate)."""
    if result is None:
        return []
    bars = error_bars(result, GATES)
    return [b for b in bars if manipulate or not b[0].startswith("manipulation")]


def family_values(result: record.SceneRecord | None, manipulate: bool = True
                  ) -> dict[str, float | None]:
    """``{family: worst value / gate}`` of a run (:data:`FAMILIES`; None: not measured)."""
    out: dict[str, float | None] = {}
    for label, value, gate, _ in run_bars(result, manipulate):
        fam = next(k for k, _ in FAMILIES if label.endswith(k))
        frac = None if value is None else (value / gate if gate > 0 else float("inf"))
        if fam not in out:
            out[fam] = frac
        elif out[fam] is not None:  # a joint without the figure is the worst of all
            out[fam] = None if frac is None else max(out[fam], frac)
    return out


def _median(values: list[float]) -> float:
    v = sorted(values)
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


def _cross(img, c, colour, r=6):
    cv2.line(img, (c[0] - r, c[1] - r), (c[0] + r, c[1] + r), colour, 2, cv2.LINE_AA)
    cv2.line(img, (c[0] - r, c[1] + r), (c[0] + r, c[1] - r), colour, 2, cv2.LINE_AA)


def _dashed(img, y, x0, x1, colour):
    for x in range(x0, x1, 10):
        cv2.line(img, (x, y), (min(x + 5, x1), y), colour, 1)


def _put(img, text, org, scale=0.45, colour=(0, 0, 0)):
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


#: Largest value / gate drawn on the sweep charts' scale (beyond it: at the top, value written).
CHART_TOP = 2.0


def draw_sweep_errors(results: record.Results) -> np.ndarray:
    """Every run's gated errors per scene and seed: a row per figure family (:data:`FAMILIES`),
    a column per scene / setting, a dot per seed at value / gate (the dashed line: the gate;
    green passes, red fails; a red cross at the top: no figure, the run failed or died).
    Returns an RGB uint8 image."""
    runs = results.runs
    groups = list(dict.fromkeys(r.group for r in runs))
    vals = {r.id: family_values(r.result, r.spec.config.get("manipulate", True)) for r in runs}
    fams = [(k, t) for k, t in FAMILIES if any(k in v for v in vals.values())]
    col, row, left, top = max(90, min(180, 900 // max(1, len(groups)))), 90, 190, 60
    w, h = max(760, left + col * len(groups) + 20), top + row * max(1, len(fams)) + 70
    img = np.full((h, w, 3), 255, np.uint8)
    _put(img, "errors per scene and seed, as a fraction of their gate (dashed: the gate)",
         (10, 24), 0.55)
    for gi, g in enumerate(groups):
        x = left + gi * col
        _put(img, g[:22], (x + 4, h - 40), 0.4)
    for fi, (key, title) in enumerate(fams):
        y0 = top + fi * row
        y1 = y0 + row - 15

        def Y(v, y0=y0 + 10, y1=y1):  # room above the scale for the values beyond it
            return int(y1 - min(v, CHART_TOP) / CHART_TOP * (y1 - y0))

        _put(img, title[:26], (8, y0 + row // 2), 0.42)
        cv2.rectangle(img, (left, y0), (left + col * len(groups), y1), (190, 190, 190), 1)
        _dashed(img, Y(1.0), left, left + col * len(groups), (0, 120, 230))
        _put(img, "1", (left - 14, Y(1.0) + 4), 0.35, (0, 90, 200))
        _put(img, "0", (left - 14, y1 + 4), 0.35)
        for gi, g in enumerate(groups):
            recs = [r for r in runs if r.group == g]
            for k, r in enumerate(recs):
                x = left + gi * col + int((k + 1) * col / (len(recs) + 1))
                v = vals[r.id].get(key)
                if key not in vals[r.id] and r.result is not None and not r.result.error:
                    continue  # the run has no such figure (e.g. no revolute joint)
                if v is None:
                    _cross(img, (x, y0 + 8), (30, 30, 220))
                    continue
                colour = (40, 170, 40) if v <= 1.0 else (220, 40, 40)
                cv2.circle(img, (x, Y(v)), 5, colour, -1, cv2.LINE_AA)
                if v > CHART_TOP:
                    _put(img, f"{v:.2g}x", (x + 8, Y(v) + 4), 0.35, (220, 40, 40))
                _put(img, str(r.spec.config["seed"]), (x - 3, y1 + 12), 0.3, (90, 90, 90))
    _put(img, "small numbers under the dots: seeds; cross at the top: no figure (error, died)",
         (10, h - 12), 0.4, (90, 90, 90))
    return img


def _axis_points(results: record.Results, name: str, axis: dict
                 ) -> list[tuple[float, record.RunRecord]]:
    """(strength, run) of every run on perturbation ``name``'s axis, the baseline runs (no
    perturbation) at ``axis["neutral"]`` when given."""
    pts = []
    for r in results.runs:
        s = r.spec
        if s.perturbation == name and s.strength is not None:
            pts.append((float(s.strength), r))
        elif not s.perturbation and axis.get("neutral") is not None:
            pts.append((float(axis["neutral"]), r))
    return sorted(pts, key=lambda p: p[0])


def draw_strength_chart(results: record.Results, name: str, axis: dict) -> np.ndarray:
    """Errors against the strength of one perturbation: axis angle (deg) and joint state (as a
    fraction of its gate: joints in degrees and millimetres alike) of each run's worst joint, a
    dot per seed, the line through the medians, the gate dashed; a red cross at the top: no
    figure (the run failed or refused). ``axis``: ``title``, ``unit``, ``neutral``."""
    pts = _axis_points(results, name, axis)
    w, h = 920, 340
    img = np.full((h, w, 3), 255, np.uint8)
    _put(img, f"{axis.get('title', name)}"[:110], (10, 20), 0.5)
    xs = sorted({x for x, _ in pts}) or [0.0]
    xmin, xmax = xs[0], xs[-1]
    span = (xmax - xmin) or 1.0
    panels = [("axis angle error (deg)", GATES["axis_angle_deg"],
               lambda r: max((j.axis_angle_deg for j in (r.joints or [])
                              if j.axis_angle_deg is not None), default=None)),
              ("joint state error / gate", 1.0,
               lambda r: family_values(r, False).get("state"))]
    for pi, (title, gate, get) in enumerate(panels):
        x0 = pi * (w // 2)
        px0, py0, px1, py1 = x0 + 55, 50, x0 + w // 2 - 15, h - 60
        cv2.rectangle(img, (px0, py0), (px1, py1), (150, 150, 150), 1)
        _put(img, title, (x0 + 10, 42), 0.45)
        values = [(x, None if r.result is None else get(r.result)) for x, r in pts]
        top = max([2 * gate] + [min(v, 10 * gate) for _, v in values if v is not None]) * 1.1

        def X(x, px0=px0, px1=px1):
            return int(px0 + 12 + (x - xmin) / span * (px1 - px0 - 24))

        def Y(y, py0=py0, py1=py1, top=top):
            return int(py1 - min(y, top) / top * (py1 - py0))

        for k in range(5):
            _put(img, f"{top * k / 4:.2g}", (x0 + 8, Y(top * k / 4) + 4), 0.35)
        for x in xs:
            _put(img, f"{x:g}", (X(x) - 10, py1 + 16), 0.35)
        _put(img, f"strength ({axis.get('unit', '')})", ((px0 + px1) // 2 - 50, py1 + 34), 0.4)
        _dashed(img, Y(gate), px0, px1, (0, 120, 230))
        _put(img, f"gate {gate:g}", (px1 - 70, Y(gate) - 5), 0.35, (0, 90, 200))
        medians = []
        for x in xs:
            at = [v for xx, v in values if xx == x]
            ok = [v for v in at if v is not None]
            if ok:
                medians.append((X(x), Y(_median(ok))))
        for a, b in zip(medians, medians[1:], strict=False):
            cv2.line(img, a, b, (40, 90, 200), 2, cv2.LINE_AA)
        for x, v in values:
            if v is None:
                _cross(img, (X(x), py0 + 10), (30, 30, 220))
                continue
            cv2.circle(img, (X(x), Y(v)), 5, (40, 170, 40) if v <= gate else (220, 40, 40), -1,
                       cv2.LINE_AA)
    _put(img, "a dot per seed (green within the gate, red beyond), line through the medians; "
         "cross at the top: the run gave no figure", (10, h - 8), 0.38, (90, 90, 90))
    return img
