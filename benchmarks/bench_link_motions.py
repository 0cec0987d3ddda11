"""Where a joint's error comes from: each moving link's A -> B motion against the truth, by the
evidence it is fitted to (issue 23).

Usage: python benchmarks/bench_link_motions.py RUNS [scene ...] [--weights 0.3 1]

RUNS is the ``--out`` folder of ``benchmarks/bench_gates.py`` (or of a sweep): its ``runs/*/``
hold each run's ``results.json`` and its ``cache/`` the reconstructions. Nothing is
reconstructed: each moving link's motion is refitted from its links stage (the matches, their
weight matrices, the dense points and their labels, as the run left them) by
:func:`artrecon.surface_fit.surface_refit` (the pipeline's own step) with

- the matches alone (the surface's weight 1e-9: the robust refit's optimum),
- the matches and the dense surface at each ``--weights`` (0.3: the shipped
  :attr:`artrecon.surface_fit.SurfaceConfig.weight`, the motion the joints are made from),
- the dense surface alone (the matches' weight 1e-6: it holds a link across its surface only,
  so its error is large along the surface and says how far the surface pulls the others),

and each is compared with the true motion of the link (the scene's link poses in A and B; the
runs' models are in the robot's frame, as the main job's FK poses give them). Prints one line
per link, the rotation errors in degrees, and each column's median, RMS and largest; the joints'
axis errors are in the runs' own ``results.json``. The truth is read here for scoring only.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from artrecon.configuration import load_configuration
from artrecon.geometry import rotation_angle
from artrecon.links_stage import load_links
from artrecon.surface_fit import SurfaceConfig, surface_refit
from sim.scene import load_scene


def reconstructions(runs_dir: Path) -> dict[str, Path]:
    """``{run id: its reconstruction folder}``: the cached reconstructions whose configuration-A
    images lie in that run's folder."""
    found = {}
    for model in sorted((runs_dir / "cache").glob("reconstruct-*/model/model.json")):
        images = Path(json.loads(model.read_text())["metadata"]["images_a"]).parts
        if "runs" in images:
            found[images[images.index("runs") + 1]] = model.parent
    return found


def link_errors(run: Path, folder: Path, weights: list[float]) -> list[dict]:
    """Per moving link of one run: the rotation error (deg) of each refit (module docstring)."""
    result = next(iter(json.loads((run / "results.json").read_text())["scenes"].values()))
    names = result.get("link_correspondence") or {}
    scene = load_scene(result["scene"])
    true_a, true_b = scene.link_poses("a"), scene.link_poses("b")
    confs = {c: load_configuration(folder / c) for c in "ab"}
    links = load_links(folder / "links", confs)
    seg = links.segmentation
    moved = {k: true_b[names[f"link_{k}"]] @ np.linalg.inv(true_a[names[f"link_{k}"]])
             for k in range(seg.n_links)
             if k != links.root and names.get(f"link_{k}") in true_a}

    def errors(segmentation, weight: float) -> dict[int, float]:
        refitted, _ = surface_refit(segmentation, links.root, links.points_a, links.points_b,
                                    confs["a"].dense, confs["b"].dense, links.labels_a,
                                    links.labels_b, SurfaceConfig(weight=weight))
        return {k: float(np.degrees(rotation_angle(
            np.asarray(refitted.transforms[k].rotation) @ truth[:3, :3].T)))
            for k, truth in moved.items()}

    fits = {"matches only": errors(seg, 1e-9)}
    fits.update({f"surface {w:g}": errors(seg, w) for w in weights})
    # the surface alone: the matches' weights a millionth of theirs
    fits["surface only"] = errors(replace(
        seg, precisions=None if seg.precisions is None else seg.precisions * 1e-6,
        weights=1e-6 * (np.ones(len(seg.labels)) if seg.weights is None else seg.weights)),
        1.0)
    labels = np.asarray(seg.labels)
    return [{"run": run.name, "link": names[f"link_{k}"], "matches": int(np.sum(labels == k)),
             **{fit: errs[k] for fit, errs in fits.items()}} for k in sorted(moved)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", type=Path, help="bench_gates.py's --out folder")
    ap.add_argument("scenes", nargs="*", help="only these scenes (default: all)")
    ap.add_argument("--weights", type=float, nargs="+", default=[SurfaceConfig.weight, 1.0],
                    help="surface weights to refit with beside the matches alone")
    args = ap.parse_args(argv)
    if not (args.runs / "runs").is_dir():
        print(f"{args.runs} holds no runs/ folder: give the --out folder of "
              "benchmarks/bench_gates.py", file=sys.stderr)
        return 2
    folders = reconstructions(args.runs)
    rows = []
    for run in sorted(p for p in (args.runs / "runs").iterdir() if p.is_dir()):
        if run.name not in folders or (args.scenes and
                                       run.name.rsplit("-seed", 1)[0] not in args.scenes):
            continue
        if not (folders[run.name] / "links" / "links.npz").is_file():
            print(f"{run.name}: its reconstruction has no links stage (a failed run?); left out",
                  file=sys.stderr)
            continue
        rows += link_errors(run, folders[run.name], args.weights)
    if not rows:
        print(f"no runs with a reconstruction under {args.runs}", file=sys.stderr)
        return 1
    columns = [k for k in rows[0] if k not in ("run", "link", "matches")]
    print("rotation error of each moving link's A -> B motion, deg")
    print(f"{'run':26s} {'link':20s} {'matches':>7s} " + " ".join(f"{c:>13s}" for c in columns))
    for r in rows:
        print(f"{r['run']:26s} {r['link'][:20]:20s} {r['matches']:7d} "
              + " ".join(f"{r[c]:13.3f}" for c in columns))
    for stat, fn in (("median", np.median), ("RMS", lambda v: np.sqrt(np.mean(v ** 2))),
                     ("largest", np.max)):
        print(f"{stat:55s} " + " ".join(f"{fn(np.array([r[c] for r in rows])):13.3f}"
                                        for c in columns))
    return 0


if __name__ == "__main__":
    sys.exit(main())
