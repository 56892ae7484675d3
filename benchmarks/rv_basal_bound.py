"""The RV's basal-support bound measured on phantoms (issue #30): how far the held cubic of
the neighbours' RV basal regions departs from an edge frame's own, where that own is right.

    env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE OPENBLAS_NUM_THREADS=1 nice -n 10 \\
        python benchmarks/rv_basal_bound.py --pathology normal --seeds 0 1 \\
        [--anatomy realistic] [--variants untouched shrink drop] > rows.jsonl

For each seed, ``generate(P, seed=S, frames=20, noise_px=1.0)`` is reconstructed, and each
frame at an edge of the RV basal slice's run (:func:`cardionurbs.anatomy.cycle.basal_edges`
of the RV endocardial stacks) is put to :func:`cardionurbs.anatomy.cycle.support_rv_basal`
with a bound of 0, which returns the frame's own basal region and the held cubic of its
sources. One JSON line per edge frame: the departure (held cubic − own) as a fraction of
the frame's RV cavity, and the frame's RV cavity own and supported against the analytic
truth. ``untouched`` frames are true geometry (support is not warranted there); ``shrink``
scales the RV contours of the basal slice at the edge frame that still traces it to 60 %
of its area (a partial tracing, as bivme-patient1's sa_01 at frame 5), and ``drop``
leaves them out (support is warranted there).

``--truth-frames N`` prints instead, per seed, the phantom's exact RV and LV cavity curves at
N frames (no reconstruction): their worst frame against the mean of its two neighbours, the
departure the Done-when of issue #30 bounds at 5 % on bivme-patient1.

``--summarise ROWS.jsonl ...`` prints the markdown table of reports/validation-quality.md
from such rows (per variant and anatomy: the departure's percentiles, how many exceed 6.6
and 8 %, the RV cavity own and supported against the truth; an altered study's rows of the
altered frame only).

``--metrics-at BOUND`` prints instead, per seed, the RV metrics against the truth with the
RV basal-support bound set to BOUND (0.08: the LV's, which main used before the RV's own):
the frames whose RV basal region was supported, ED and ES.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import importlib
import json
import math

import numpy as np

from cardionurbs import reconstruct
from cardionurbs.anatomy.cycle import lagrange_weights, support_rv_basal

generate = importlib.import_module("cardionurbs.phantom.generate")
#: the area a ``shrink`` variant leaves of the basal slice's RV contours
SHRINK_AREA = 0.6


def truth_curve(ph) -> list[float]:
    """The phantom's analytic RV cavity volume per frame (mL; method A, the realistic
    anatomy's through :func:`cardionurbs.phantom.truth_realistic.volume_curve`)."""
    if ph.anatomy.realistic:
        from cardionurbs.phantom.truth_realistic import volume_curve
        curve = volume_curve(ph.anatomy, ph.motion, float(max(ph.phases)))
    else:
        from cardionurbs.phantom.truth import analytic_volumes
        curve = functools.partial(analytic_volumes, ph.anatomy, ph.motion)
    return [curve(float(f))["rv_cavity"] for f in ph.phases]


def held_cubic(model, frame: int, sources: list[int]) -> float:
    """The cubic through the sources' own RV cavity volumes at the frame, held within the
    nearest source on each side (mL), as :func:`support_rv_basal` holds the basal regions."""
    v = np.array([model.volumes[g]["rv_cavity"] for g in sources], float)
    x = np.array([_position(model.frames, frame, g) for g in sources], float)
    return float(np.clip(lagrange_weights(x, 0.0) @ v, *sorted(v[1:3])))


def _position(frames: list[int], frame: int, g: int) -> int:
    """g's position relative to frame in the (cyclic) order of frames."""
    n = len(frames)
    d = (frames.index(g) - frames.index(frame)) % n
    return d - n if d > n // 2 else d


def beyond_both(model, frame: int, ref: str, own: float) -> float:
    """How far a frame's RV basal region lies beyond both adjacent frames' (mL; > 0 above
    both, < 0 below both, 0 between them)."""
    i = model.frames.index(frame)
    adj = [model._rv_basal_ml(model.frames[(i + d) % len(model.frames)], ref) for d in (-1, 1)]
    return max(own - max(adj), 0.0) + min(own - min(adj), 0.0)


def _edges(model) -> tuple[int | None, list[int], set[int]]:
    """(reference slice, the RV basal edge frames in order, the edge set); none without."""
    edges = model._rv_basal_edges()
    if edges is None:
        return None, [], set()
    ref, edge = edges
    return ref, sorted(edge), edge


def edge_rows(model, truth: list[float]) -> list[dict]:
    """Per RV basal edge frame: own and held-cubic basal region, departure, truth errors."""
    ref, frames, edge = _edges(model)
    out = []
    for f in frames:
        vol = model.volumes[f].get("rv_cavity", math.nan)
        s = support_rv_basal(f, model.frames, edge, ref, vol,
                             lambda g: model._rv_basal_ml(g, ref),
                             cyclic=model.cycle.cyclic, bound=0.0)
        if s is None:
            continue
        out.append({"frame": f, "rv_ml": vol, "own_basal": s.basal,
                    "used_basal": s.used, "sources": s.sources,
                    "departure": (s.used - s.basal) / vol,
                    "total_departure": held_cubic(model, f, s.sources) / vol - 1,
                    "beyond": beyond_both(model, f, ref, s.basal) / vol, "truth": truth[f],
                    "err_own": vol / truth[f] - 1, "err_supported": s.total / truth[f] - 1})
    return out


def basal_traced(model) -> list[tuple[int, str]]:
    """The edge frames that trace a slice basal to the reference one, and that slice."""
    ref, frames, _ = _edges(model)
    out = []
    for f in frames:
        stack = [s.slice for s in model.geometry[f].sections.get("rv_endo") or []]
        if stack and stack[0] != ref:
            out.append((f, stack[stack.index(ref) - 1]))
    return out


def altered(study, frame: int, slice_id: str, how: str):
    """The study with the RV contours of one slice at one frame shrunk or left out."""
    out = []
    for c in study.contours:
        if c.frame == frame and c.slice == slice_id and c.structure.startswith("rv"):
            if how == "drop":
                continue
            m = c.points.mean(axis=0)
            c = dataclasses.replace(c, points=m + (c.points - m) * math.sqrt(SHRINK_AREA))
        out.append(c)
    return dataclasses.replace(study, contours=out, warnings=list(study.warnings))


def run(pathology: str, seed: int, anatomy: str, variants: list[str]):
    """Yield one row per edge frame of the untouched and the altered studies of one seed."""
    ph = generate.generate(pathology, seed=seed, frames=20, noise_px=1.0, volume_check=False,
                           anatomy_model=anatomy)
    truth = truth_curve(ph)
    model = reconstruct(ph.study)
    head = {"pathology": pathology, "seed": seed, "anatomy": anatomy}
    if "untouched" in variants:
        for r in edge_rows(model, truth):
            yield {**head, "variant": "untouched", **r}
    for f, sl in basal_traced(model):
        for how in (v for v in variants if v != "untouched"):
            m = reconstruct(altered(ph.study, f, sl, how))
            for r in edge_rows(m, truth):
                yield {**head, "variant": how, "altered": [f, sl], **r}


def truth_departures(pathology: str, seed: int, frames: int) -> dict:
    """The worst frame of a phantom's exact RV and LV curves against its two neighbours' mean."""
    from cardionurbs.phantom.truth import analytic_volumes
    ph = generate.generate(pathology, seed=seed, frames=frames, volume_check=False)
    out = {"pathology": pathology, "seed": seed, "frames": frames}
    lv = [analytic_volumes(ph.anatomy, ph.motion, float(f))["lv_cavity"] for f in ph.phases]
    for name, v in (("rv", np.array(truth_curve(ph))), ("lv", np.array(lv))):
        d = 100 * (v / ((np.roll(v, 1) + np.roll(v, -1)) / 2) - 1)
        k = int(np.argmax(np.abs(d)))
        out[name] = {"es": int(np.argmin(v)), "worst_frame": k, "worst_pct": float(d[k])}
    return out


def metrics_at(pathology: str, seed: int, anatomy: str, bound: float) -> dict:
    """RV metrics of one phantom against its truth with the RV basal bound set to ``bound``."""
    from cardionurbs.analysis.function import measure, volume_curve
    from cardionurbs.anatomy import model as model_mod
    ph = generate.generate(pathology, seed=seed, frames=20, noise_px=1.0, volume_check=False,
                           anatomy_model=anatomy)
    model_mod.support_rv_basal = functools.partial(support_rv_basal, bound=bound)
    try:
        model = reconstruct(ph.study)
        met, vc = measure(model), volume_curve(model)
    finally:
        model_mod.support_rv_basal = support_rv_basal
    truth = ph.truth["metrics"]
    return {"pathology": pathology, "seed": seed, "anatomy": anatomy, "bound": bound,
            "ed_es": [model.ed_frame, model.es_frame],
            "truth_ed_es": [ph.truth["ed_frame"], ph.truth["es_frame"]],
            "rv_basal_supported": vc.get("rv_basal_supported"),
            **{k: [met[k], truth[k]] for k in ("RVEDV (mL)", "RVESV (mL)", "RVEF (%)")}}


def summarise(paths: list[str]) -> None:
    """Print the departure table of the rows in ``paths`` (JSON lines of this script)."""
    rows = [json.loads(line) for p in paths for line in open(p)]
    rows = [r for r in rows if r["variant"] == "untouched" or r["frame"] == r["altered"][0]]
    print("| set | edge frames | median | p95 | p99 | max | > 6.6 % | > 8 % "
          "| RV own vs truth, mean / max abs (%) | RV supported vs truth, mean / max abs (%) |")
    print("|---" * 10 + "|")
    for var in ("untouched", "shrink", "drop"):
        for an in ("ideal", "realistic", None):
            g = [r for r in rows if r["variant"] == var and an in (None, r["anatomy"])]
            if not g:
                continue
            d = 100 * np.abs([r["departure"] for r in g])
            own, sup = (100 * np.abs([r[k] for r in g]) for k in ("err_own", "err_supported"))
            q = np.percentile(d, [50, 95, 99])
            print(f"| {var} {an or 'all'} | {len(g)} | {q[0]:.1f} | {q[1]:.1f} | {q[2]:.1f} "
                  f"| {d.max():.1f} | {(d > 6.6).sum()} | {(d > 8).sum()} "
                  f"| {own.mean():.1f} / {own.max():.1f} | {sup.mean():.1f} / {sup.max():.1f} |")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pathology", default="normal", choices=("normal", "mr", "phtn"))
    ap.add_argument("--anatomy", default="ideal", choices=("ideal", "realistic"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--variants", nargs="+", default=["untouched"],
                    choices=("untouched", "shrink", "drop"))
    ap.add_argument("--truth-frames", type=int, default=0)
    ap.add_argument("--metrics-at", type=float, default=None)
    ap.add_argument("--summarise", nargs="+", metavar="ROWS.jsonl")
    a = ap.parse_args(argv)
    if a.summarise:
        return summarise(a.summarise)
    for seed in a.seeds:
        if a.metrics_at is not None:
            print(json.dumps(metrics_at(a.pathology, seed, a.anatomy, a.metrics_at)), flush=True)
            continue
        if a.truth_frames:
            print(json.dumps(truth_departures(a.pathology, seed, a.truth_frames)), flush=True)
            continue
        for row in run(a.pathology, seed, a.anatomy, a.variants):
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
