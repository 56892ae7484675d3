"""Phantoms at 1 px noise with two frames corrupted: ES and EF against the truth (issue #30).

    env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE OPENBLAS_NUM_THREADS=1 \\
        python benchmarks/corrupted_frames.py [--pathology normal] [--noise-px 1] \\
        [--record DIR] SEED...

For each seed, ``cardionurbs.phantom.generate.generate(P, seed=S, frames=20, noise_px=1.0)``
is reconstructed untouched and corrupted as
``tests/test_cycle.py::test_phantom_corrupted_frames_keep_es_and_ef`` does it: 3 mm in-plane
noise on every point of the frame before the truth's ES, and every other contour of each
structure and view left out at ES + 3. One markdown row per seed: the truth's ES frame and
LVEF, then for the untouched and the corrupted study the ES frame, LVEF − truth (points) and
the frames supported by their neighbours (:mod:`cardionurbs.anatomy.cycle`).

``--record DIR`` also writes, per study, the arguments the model passed to
:func:`cardionurbs.anatomy.cycle.check_curve` (the raw LV curve, the contour counts and the
basal support) and the phantom's analytic truth curve, as JSON, so that a change of the rule
can be tried on them without reconstructing again.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import sys
from pathlib import Path

import numpy as np

from cardionurbs import reconstruct
from cardionurbs.analysis.function import measure
from cardionurbs.anatomy import model as model_mod

generate = importlib.import_module("cardionurbs.phantom.generate")


def corrupt(study, frame: int, how: str, seed: int = 0):
    """The study with one frame's contours halved (``"half"``: every other contour of each
    structure and view left out) or with 3 mm in-plane noise on every point (``"noise"``),
    (``tests/test_cycle.py`` corrupts its studies with this function)."""
    rng = np.random.default_rng(seed)
    out, count = [], {}
    for c in study.contours:
        if c.frame != frame:
            out.append(c)
        elif how == "half":
            k = count[c.structure, c.view] = count.get((c.structure, c.view), 0) + 1
            if k % 2:
                out.append(c)
        else:
            n = study.image(c.image).normal
            e = rng.normal(0.0, 3.0, c.points.shape)
            out.append(dataclasses.replace(c, points=c.points + e - np.outer(e @ n, n)))
    return dataclasses.replace(study, contours=out, warnings=list(study.warnings))


def truth_curve(ph) -> list[float]:
    """The phantom's analytic LV cavity volume per frame (mL): method A of
    :func:`cardionurbs.phantom.truth.analytic_volumes`."""
    from cardionurbs.phantom.truth import analytic_volumes
    return [analytic_volumes(ph.anatomy, ph.motion, float(f))["lv_cavity"] for f in ph.phases]


class _Recorder:
    """Wraps the model's ``check_curve`` to keep its last arguments."""

    def __init__(self):
        self.calls: list[dict] = []
        self._orig = model_mod.check_curve

    def __call__(self, volumes, *, contours=None, basal=None, **kw):
        self.calls.append({
            "volumes": {str(f): v for f, v in volumes.items()},
            "contours": {str(f): n for f, n in (contours or {}).items()},
            "basal": {str(f): dataclasses.asdict(b) for f, b in (basal or {}).items()}})
        return self._orig(volumes, contours=contours, basal=basal, **kw)


def run(study, recorder: _Recorder | None):
    """Reconstruct and measure; returns (ES frame, LVEF %, supported frames, LVESV, LVEDV)."""
    if recorder is not None:
        model_mod.check_curve = recorder
    try:
        model = reconstruct(study)
    finally:
        if recorder is not None:
            model_mod.check_curve = recorder._orig
    m = measure(model)
    return (model.es_frame, m["LVEF (%)"], sorted(model.supported), m["LVESV (mL)"],
            m["LVEDV (mL)"], model.ed_frame)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("seeds", nargs="+", type=int)
    ap.add_argument("--pathology", default="normal")
    ap.add_argument("--noise-px", type=float, default=1.0)
    ap.add_argument("--record", type=Path, default=None)
    a = ap.parse_args(argv)
    print("| phantom | truth ES, LVEF | untouched ES, EF − truth, supported "
          "| corrupted ES, EF − truth, supported |")
    print("|---|---|---|---|")
    for s in a.seeds:
        ph = generate.generate(a.pathology, seed=s, frames=20, noise_px=a.noise_px,
                               volume_check=False)
        es, ef = ph.truth["es_frame"], ph.truth["metrics"]["LVEF (%)"]
        cells, rec = [], {}
        studies = {"untouched": ph.study,
                   "corrupted": corrupt(corrupt(ph.study, es - 1, "noise"), es + 3, "half")}
        for name, study in studies.items():
            r = _Recorder() if a.record else None
            got_es, got_ef, sup, esv, edv, ed = run(study, r)
            cells.append(f"{got_es}, {got_ef - ef:+.2f}, {sup}")
            if r is not None:
                rec[name] = {**r.calls[-1], "es": got_es, "ed": ed, "lvef": got_ef,
                             "lvesv": esv, "lvedv": edv, "supported": sup}
        print(f"| {a.pathology} {s} | {es}, {ef:.2f} | {cells[0]} | {cells[1]} |", flush=True)
        if a.record:
            a.record.mkdir(parents=True, exist_ok=True)
            rec["truth"] = {"es": es, "lvef": ef, "lv_cavity": truth_curve(ph)}
            tag = "" if a.noise_px == 1.0 else f"_noise{a.noise_px:g}"
            (a.record / f"{a.pathology}{s}{tag}.json").write_text(json.dumps(rec))


if __name__ == "__main__":
    main(sys.argv[1:])
