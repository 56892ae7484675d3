"""Valve annuli of the realistic phantom: how far the mitral and tricuspid annulus points depart
from their best-fit planes at ED, and how much the pulmonary annulus (outflow tracts) narrows
from ED to ES. Prints a markdown table (docs/phantoms.md; reports/validation-realistic.md).

Usage::

    python benchmarks/phantom_annuli.py [--seeds 5]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cardionurbs.geometry import fit_plane  # noqa: E402
from cardionurbs.phantom import annotate  # noqa: E402
from cardionurbs.phantom import outflow as ofl  # noqa: E402
from cardionurbs.phantom.generate import generate  # noqa: E402


def departure(points: np.ndarray) -> float:
    """Largest distance (mm) of points from their least-squares plane."""
    c, n = fit_plane(points)
    return float(np.abs((points - c) @ n).max())


def ring_shape(ring: np.ndarray) -> tuple[float, float]:
    """(area mm², smallest in-plane extent mm) of a closed annulus ring."""
    q = (ring - ring.mean(axis=0)) @ np.linalg.svd(ring - ring.mean(axis=0))[2][:2].T
    area = 0.5 * abs(float(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - q[:, 1] * np.roll(q[:, 0], -1))))
    return area, float((q.max(axis=0) - q.min(axis=0)).min())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args(argv)
    print("| preset | seed | mitral departure (mm) | tricuspid dip h_t (mm) | tricuspid departure (mm) "
          "| pulmonary annulus ES/ED (outflow tracts): area | equivalent diameter | narrowest extent |")
    print("|---|---|---|---|---|---|---|---|")
    agg = {k: [] for k in ("mit", "tri0", "area", "diam", "narrow")}
    for p in ("normal", "mr", "phtn"):
        for seed in range(args.seeds):
            body = generate(p, seed=seed, frames=4, anatomy_model="realistic", outflow=False,
                            volume_check=False)
            mit = departure(annotate.bend(body.anatomy, annotate.landmarks(body.anatomy, body.motion,
                                                                            0.0)["mitral"]))
            tri0 = departure(annotate.bend(body.anatomy, annotate.landmarks(body.anatomy, body.motion,
                                                                             0.0)["tricuspid"]))
            ph = generate(p, seed=seed, frames=4, anatomy_model="realistic", outflow=True,
                          volume_check=False)
            an, mo = ph.anatomy, ph.motion
            ring = np.asarray(ofl.pulmonary_ring(an, 97))
            (a0, n0), (a1, n1) = (ring_shape(annotate.bend(an, mo.forward(an, ring, f)))
                                  for f in (0.0, float(ph.phases[ph.es_frame])))
            row = {"mit": mit, "tri0": tri0, "area": a1 / a0, "diam": np.sqrt(a1 / a0), "narrow": n1 / n0}
            for k, v in row.items():
                agg[k].append(v)
            print(f"| {p} | {seed} | {mit:.2f} | {body.anatomy.tricuspid_dip:.2f} | {tri0:.2f} | {row['area']:.2f} | "
                  f"{row['diam']:.2f} | {row['narrow']:.2f} |")
    print(f"| all | {3 * args.seeds} subjects | {min(agg['mit']):.2f}–{max(agg['mit']):.2f} | | "
          f"{min(agg['tri0']):.2f}–{max(agg['tri0']):.2f} | {min(agg['area']):.2f}–{max(agg['area']):.2f} | "
          f"{min(agg['diam']):.2f}–{max(agg['diam']):.2f} | {min(agg['narrow']):.2f}–{max(agg['narrow']):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
