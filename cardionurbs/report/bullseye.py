"""AHA 17-segment bull's-eye plots (Cerqueira et al., Circulation 2002, Fig. 2 layout).

Rings from the centre: segment 17 (apex), apical 13–16, mid 7–12, basal 1–6.
Anterior at the top, septum on the left, inferior at the bottom, lateral on
the right (the standard display, seen from the apex): basal/mid segment k
spans 60° from 60° + 60°·((k − 1) mod 6), counter-clockwise from the right;
apical segment 13 + j spans 90° from 45° + 90° j. Each segment is labelled
with its number and value; the colour bar carries the quantity and unit.
Segments without a value are hatched grey.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import io
import textwrap

import matplotlib
import numpy as np
from matplotlib import cm, colors
from matplotlib.figure import Figure

from cardionurbs.io import atomic
from cardionurbs.safe import plain_text

#: (figure name, column stem, title, unit, colour map, diverging)
QUANTITIES = (
    ("fig13_bullseye_thickness", "WT_AHA_{k} (mm)", "Wall thickness at ED", "mm", "viridis", False),
    ("fig14_bullseye_thickening", "Thickening_AHA_{k} (%)", "Wall thickening ED → ES", "%",
     "viridis", False),
    ("fig15_bullseye_ecc", "Ecc_AHA_{k} (%)", "Circumferential strain Ecc at ES", "%", "RdBu_r", True),
    ("fig16_bullseye_ell", "Ell_AHA_{k} (%)", "Longitudinal strain Ell at ES", "%", "RdBu_r", True),
    ("fig17_bullseye_err", "Err_AHA_{k} (%)", "Radial strain Err at ES", "%", "RdBu_r", True),
)


def segment_wedges() -> dict[int, tuple[float, float, float, float]]:
    """Segment -> (start angle rad, width rad, inner radius, outer radius) of the layout."""
    out = {17: (0.0, 2 * np.pi, 0.0, 1.0)}
    for k in range(1, 13):
        ring = 3.0 if k <= 6 else 2.0
        out[k] = (np.radians(60.0 + 60.0 * ((k - 1) % 6)), np.radians(60.0), ring, ring + 1.0)
    for j in range(4):
        out[13 + j] = (np.radians(45.0 + 90.0 * j), np.radians(90.0), 1.0, 2.0)
    return out


def draw_bullseye(ax, values: Mapping[int, float], *, cmap: str = "viridis", norm=None,
                  fmt: str = "{:.1f}") -> colors.Normalize:
    """Draw the segments of ``values`` (segment -> value, NaN/absent = no value) on a polar axes."""
    vals = np.array([values.get(k, np.nan) for k in range(1, 18)], float)
    fin = vals[np.isfinite(vals)]
    if norm is None:
        lo, hi = (float(fin.min()), float(fin.max())) if len(fin) else (0.0, 1.0)
        norm = colors.Normalize(lo, hi if hi > lo else lo + 1.0)
    cmap_ = matplotlib.colormaps[cmap]
    wedges = segment_wedges()
    seg = np.array(list(wedges.values()))                 # (start, width, inner, outer) per segment
    ok = [values.get(k) is not None and np.isfinite(values.get(k, np.nan)) for k in wedges]
    # one bar call for the 17 segments (one container, not 17): the same patches
    ax.bar(seg[:, 0] + seg[:, 1] / 2, seg[:, 3] - seg[:, 2], width=seg[:, 1], bottom=seg[:, 2],
           color=[cmap_(norm(values[k])) if good else "#dddddd" for k, good in zip(wedges, ok)],
           edgecolor="white", linewidth=1.5, hatch=[None if good else "//" for good in ok],
           align="center")
    for k, (a0, w, r0, r1) in wedges.items():
        v = values.get(k, np.nan)
        ok = v is not None and np.isfinite(v)
        ang, rad = (0.0, 0.0) if k == 17 else (a0 + w / 2, 0.5 * (r0 + r1))
        rgba = cmap_(norm(v)) if ok else (0.87, 0.87, 0.87, 1)
        dark = (0.299 * rgba[0] + 0.587 * rgba[1] + 0.114 * rgba[2]) < 0.5
        ax.text(ang, rad, f"{k}\n" + (fmt.format(v) if ok else "–"), ha="center", va="center",
                fontsize=7, color="white" if dark else "black")
    ax.set_ylim(0, 4)
    ax.set_axis_off()
    return norm


def bullseye_figure(values: Mapping[int, float], title: str, unit: str, path: Path, *,
                    cmap: str = "viridis", diverging: bool = False, caption: str = "",
                    label: str | None = None) -> Path:
    """One bull's-eye PNG with a colour bar labelled with the quantity and unit."""
    fig = Figure(figsize=(4.6, 4.4), dpi=100)
    ax = fig.add_axes([0.04, 0.14, 0.7, 0.74], projection="polar")
    label = label or title
    fin = np.array([v for v in values.values() if v is not None and np.isfinite(v)])
    norm = None
    if diverging and len(fin):
        m = float(np.abs(fin).max()) or 1.0
        norm = colors.TwoSlopeNorm(0.0, -m, m) if fin.min() < 0 < fin.max() else colors.Normalize(
            float(fin.min()), float(fin.max()) if np.ptp(fin) > 0 else float(fin.min()) + 1.0)
    norm = draw_bullseye(ax, values, cmap=cmap, norm=norm)
    sm = cm.ScalarMappable(norm=norm, cmap=matplotlib.colormaps[cmap])
    cax = fig.add_axes([0.8, 0.2, 0.04, 0.62])
    fig.colorbar(sm, cax=cax, label=f"{label} ({unit})")
    fig.suptitle(plain_text(title), fontsize=9)
    fig.text(0.02, 0.02, plain_text(textwrap.fill(caption, 95)), fontsize=6.5, ha="left",
             va="bottom")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    atomic.write_bytes(path, buf.getvalue())
    return path


def segment_values(metrics: Mapping[str, float] | None, stem: str) -> dict[int, float]:
    """Segment -> value of one column family (1..16) from a metrics dict."""
    out = {}
    for k in range(1, 17):
        v = (metrics or {}).get(stem.format(k=k))
        out[k] = float(v) if v is not None else np.nan
    return out


def quantity_figure(metrics: Mapping[str, float] | None, quantity: tuple, subject: str,
                    out: Path, frames: str = "") -> tuple[Path, str] | str:
    """The bull's-eye PNG of one entry of :data:`QUANTITIES`: (path, caption), or the reason
    it is not drawn (no value in any segment)."""
    name, stem, title, unit, cmap, diverging = quantity
    vals = segment_values(metrics, stem)
    if not any(np.isfinite(v) for v in vals.values()):
        return f"no {stem.split('_AHA')[0]} values per AHA segment for this study"
    caption = (f"{subject}{', ' + frames if frames else ''}: {title} per AHA segment (1-6 basal, 7-12 mid, 13-16 apical; "
               "anterior up, septum left, seen from the apex). Grey hatched: no value.")
    label = stem.split("_AHA")[0].replace("WT", "Wall thickness")
    path = bullseye_figure(vals, title, unit, Path(out) / f"{name}.png", cmap=cmap,
                           diverging=diverging, caption=caption, label=label)
    return path, caption
