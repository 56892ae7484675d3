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
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from cardionurbs.io import atomic
from cardionurbs.safe import plain_text

#: the fixed colour scale of each quantity (unit of the quantity), the same for every study,
#: so that a segment's colour reads the same in every report and noise does not look like
#: disease. The spans are a display choice wide enough for healthy and impaired adult LVs
#: (wall thickness 0-20 mm; thickening -20-100 %; Ecc, Ell +-30 %; Err +-60 %), stated in
#: the colour bar; values beyond them take the end colours (the bar's arrows)
SCALES = {"WT": (0.0, 20.0), "Thickening": (-20.0, 100.0), "Ecc": (-30.0, 30.0),
          "Ell": (-30.0, 30.0), "Err": (-60.0, 60.0)}

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
    """Segment -> (start angle rad, width rad, inner radius, outer radius) of the layout.

    Returns
    -------
    dict of int to tuple of float
        AHA segment 1..17 -> (start angle in rad, angular width in rad, inner radius, outer
        radius) in the plot's radius units (basal ring 3-4, mid 2-3, apical 1-2, apex 0-1).
    """
    out = {17: (0.0, 2 * np.pi, 0.0, 1.0)}
    for k in range(1, 13):
        ring = 3.0 if k <= 6 else 2.0
        out[k] = (np.radians(60.0 + 60.0 * ((k - 1) % 6)), np.radians(60.0), ring, ring + 1.0)
    for j in range(4):
        out[13 + j] = (np.radians(45.0 + 90.0 * j), np.radians(90.0), 1.0, 2.0)
    return out


def _segment_style(values: Mapping[int, float], cmap: str, norm, fmt: str) -> tuple:
    """(norm, face colours, hatches, label texts, label colours) of the 17 segments, in
    :func:`segment_wedges` order: a segment without a value is light grey and hatched; a
    label is white on a dark segment (luma < 0.5), else black."""
    vals = np.array([values.get(k, np.nan) for k in range(1, 18)], float)
    fin = vals[np.isfinite(vals)]
    if norm is None:
        lo, hi = (float(fin.min()), float(fin.max())) if len(fin) else (0.0, 1.0)
        norm = colors.Normalize(lo, hi if hi > lo else lo + 1.0)
    cmap_ = matplotlib.colormaps[cmap]
    faces, hatches, texts, ink = [], [], [], []
    for k in segment_wedges():
        v = values.get(k, np.nan)
        ok = v is not None and np.isfinite(v)
        rgba = cmap_(norm(v)) if ok else (0.87, 0.87, 0.87, 1)
        faces.append(cmap_(norm(v)) if ok else "#dddddd")
        hatches.append(None if ok else "//")
        texts.append(f"{k}\n" + (fmt.format(v) if ok else "–"))
        dark = (0.299 * rgba[0] + 0.587 * rgba[1] + 0.114 * rgba[2]) < 0.5
        ink.append("white" if dark else "black")
    return norm, faces, hatches, texts, ink


def _label_positions() -> list[tuple[float, float]]:
    """(angle rad, radius) of each segment's label, :func:`segment_wedges` order."""
    return [(0.0, 0.0) if k == 17 else (a0 + w / 2, 0.5 * (r0 + r1))
            for k, (a0, w, r0, r1) in segment_wedges().items()]


def draw_bullseye(ax, values: Mapping[int, float], *, cmap: str = "viridis", norm=None,
                  fmt: str = "{:.1f}") -> colors.Normalize:
    """Draw the segments of ``values`` (segment -> value, NaN/absent = no value) on a polar axes.

    Parameters
    ----------
    ax : matplotlib.projections.polar.PolarAxes
        The axes drawn on.
    values : mapping of int to float
        AHA segment (1..17) -> value in the quantity's unit; NaN or absent: no value (grey,
        hatched).
    cmap : str, optional
        A matplotlib colour map name.
    norm : matplotlib.colors.Normalize, optional
        The colour scale; default: the values' range.
    fmt : str, optional
        Format of the value printed in each segment.

    Returns
    -------
    matplotlib.colors.Normalize
        The colour scale used (for a colour bar).
    """
    norm, faces, hatches, texts, ink = _segment_style(values, cmap, norm, fmt)
    seg = np.array(list(segment_wedges().values()))  # (start, width, inner, outer) per segment
    # one bar call for the 17 segments (one container, not 17): the same patches
    ax.bar(seg[:, 0] + seg[:, 1] / 2, seg[:, 3] - seg[:, 2], width=seg[:, 1], bottom=seg[:, 2],
           color=faces, edgecolor="white", linewidth=1.5, hatch=hatches, align="center")
    for (ang, rad), text, c in zip(_label_positions(), texts, ink):
        ax.text(ang, rad, text, ha="center", va="center", fontsize=7, color=c)
    ax.set_ylim(0, 4)
    ax.set_axis_off()
    return norm


def fixed_norm(stem: str, diverging: bool):
    """The colour normalisation of a quantity (:data:`SCALES`; diverging ones centred on 0).

    Parameters
    ----------
    stem : str
        The column family, e.g. ``"WT_AHA_{k} (mm)"`` (its part before ``_AHA`` keys :data:`SCALES`).
    diverging : bool
        Centre the scale on 0 when it straddles 0.

    Returns
    -------
    matplotlib.colors.Normalize
        ``TwoSlopeNorm`` about 0 or a plain ``Normalize`` over the quantity's fixed range.
    """
    lo, hi = SCALES[stem.split("_AHA")[0]]
    return colors.TwoSlopeNorm(0.0, lo, hi) if diverging and lo < 0 < hi else colors.Normalize(lo, hi)


def _norm_of(values: Mapping[int, float], diverging: bool):
    """The data-range colour normalisation (only when a quantity has no fixed scale):
    diverging quantities symmetric about 0 when their values straddle it; None (the
    segments' range, :func:`_segment_style`) else."""
    fin = np.array([v for v in values.values() if v is not None and np.isfinite(v)])
    if not (diverging and len(fin)):
        return None
    m = float(np.abs(fin).max()) or 1.0
    return colors.TwoSlopeNorm(0.0, -m, m) if fin.min() < 0 < fin.max() else colors.Normalize(
        float(fin.min()), float(fin.max()) if np.ptp(fin) > 0 else float(fin.min()) + 1.0)


class BullseyeCanvas:
    """One bull's-eye figure drawn once and re-used for every quantity of a study.

    Making a figure with a polar axes, its 17 wedges and labels costs more than drawing
    it (about 0.06 s of the 0.18 s a bull's-eye PNG took): the wedges, labels, title and
    caption are made once and only re-coloured and re-labelled per quantity; the colour
    bar, whose ticks depend on the quantity, gets a fresh axes each time. The PNG is the
    one :func:`bullseye_figure` draws on a new figure."""

    def __init__(self) -> None:
        self.fig = Figure(figsize=(4.6, 4.4), dpi=100)
        self.ax = self.fig.add_axes((0.03, 0.14, 0.66, 0.74), projection="polar")
        draw_bullseye(self.ax, {}, cmap="viridis")
        self.bars = list(self.ax.containers[0])
        self.labels = list(self.ax.texts)
        self.title = self.fig.suptitle("", fontsize=9)
        self.caption = self.fig.text(0.02, 0.02, "", fontsize=6.5, ha="left", va="bottom")
        self.cax: Axes | None = None

    def render(self, values: Mapping[int, float], title: str, unit: str, path: Path, *,
               cmap: str = "viridis", diverging: bool = False, caption: str = "",
               label: str | None = None, norm=None) -> Path:
        """Draw one quantity and write the PNG (atomically); see :func:`bullseye_figure`.

        Parameters
        ----------
        values : mapping of int to float
            AHA segment -> value in ``unit`` (NaN or absent: no value).
        title : str
            The figure's title.
        unit : str
            The unit shown on the colour bar (``"mm"``, ``"%"``).
        path : pathlib.Path
            The PNG to write.
        cmap : str, optional
            A matplotlib colour map name.
        diverging : bool, optional
            Without ``norm``: a scale symmetric about 0 when the values straddle it.
        caption : str, optional
            The text under the figure.
        label : str or None, optional
            The colour bar's quantity name (default ``title``).
        norm : matplotlib.colors.Normalize, optional
            A fixed colour scale (stated in the bar); default: the values' range.

        Returns
        -------
        pathlib.Path
            ``path``.
        """
        fixed = norm is not None
        norm, faces, hatches, texts, ink = _segment_style(
            values, cmap, norm if fixed else _norm_of(values, diverging), "{:.1f}")
        for bar, face, hatch in zip(self.bars, faces, hatches):
            bar.set_facecolor(face)
            bar.set_hatch(hatch)
        for t, text, c in zip(self.labels, texts, ink):
            t.set_text(text)
            t.set_color(c)
        if self.cax is not None:
            self.cax.remove()
        self.cax = self.fig.add_axes((0.74, 0.2, 0.04, 0.62))
        sm = cm.ScalarMappable(norm=norm, cmap=matplotlib.colormaps[cmap])
        text = f"{label or title} ({unit})"
        if fixed:
            text += f"\nfixed scale {norm.vmin:g} to {norm.vmax:g} {unit}"
        self.fig.colorbar(sm, cax=self.cax, label=text, extend="both" if fixed else "neither")
        self.title.set_text(plain_text(title))
        self.caption.set_text(plain_text(textwrap.fill(caption, 84)))
        buf = io.BytesIO()
        self.fig.savefig(buf, format="png", dpi=100)
        atomic.write_bytes(path, buf.getvalue())
        return path


def bullseye_figure(values: Mapping[int, float], title: str, unit: str, path: Path, *,
                    cmap: str = "viridis", diverging: bool = False, caption: str = "",
                    label: str | None = None, canvas: BullseyeCanvas | None = None,
                    norm=None) -> Path:
    """One bull's-eye PNG with a colour bar labelled with the quantity and unit (drawn on
    ``canvas`` when given: the figures of one study share one); ``norm``: a fixed colour
    scale (:func:`fixed_norm`, stated in the bar), else the values' range.

    Parameters
    ----------
    values : mapping of int to float
        AHA segment -> value in ``unit`` (NaN or absent: no value).
    title : str
        The figure's title.
    unit : str
        The unit shown on the colour bar.
    path : pathlib.Path
        The PNG to write (atomically).
    cmap : str, optional
        A matplotlib colour map name.
    diverging : bool, optional
        Without ``norm``: a scale symmetric about 0 when the values straddle it.
    caption : str, optional
        The text under the figure.
    label : str or None, optional
        The colour bar's quantity name (default ``title``).
    canvas : BullseyeCanvas or None, optional
        A canvas to re-use (default: a new one).
    norm : matplotlib.colors.Normalize, optional
        A fixed colour scale.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    return (canvas or BullseyeCanvas()).render(values, title, unit, path, cmap=cmap,
                                               diverging=diverging, caption=caption, label=label,
                                               norm=norm)


def segment_values(metrics: Mapping[str, float] | None, stem: str) -> dict[int, float]:
    """Segment -> value of one column family (1..16) from a metrics dict.

    Parameters
    ----------
    metrics : mapping of str to float or None
        A docs/metrics.md dict.
    stem : str
        The column family with a ``{k}`` field, e.g. ``"WT_AHA_{k} (mm)"``.

    Returns
    -------
    dict of int to float
        Segment 1..16 -> value in the column's unit (NaN where absent).
    """
    out = {}
    for k in range(1, 17):
        v = (metrics or {}).get(stem.format(k=k))
        out[k] = float(v) if v is not None else np.nan
    return out


def quantity_figure(metrics: Mapping[str, float] | None, quantity: tuple, subject: str,
                    out: Path, frames: str = "", canvas: BullseyeCanvas | None = None
                    ) -> tuple[Path, str] | str:
    """The bull's-eye PNG of one entry of :data:`QUANTITIES`: (path, caption), or the reason
    it is not drawn (no value in any segment).

    Parameters
    ----------
    metrics : mapping of str to float or None
        A docs/metrics.md dict.
    quantity : tuple
        One entry of :data:`QUANTITIES`: (file name, column stem, title, unit, colour map,
        diverging).
    subject : str
        The study's subject, for the caption.
    out : pathlib.Path
        The folder the PNG goes to.
    frames : str, optional
        Which frame the values are at (``"ES frame 7"``), for the caption.
    canvas : BullseyeCanvas or None, optional
        A canvas to re-use.

    Returns
    -------
    tuple of (pathlib.Path, str) or str
        (PNG path, caption), or why the figure is not drawn.
    """
    name, stem, title, unit, cmap, diverging = quantity
    vals = segment_values(metrics, stem)
    if not any(np.isfinite(v) for v in vals.values()):
        return f"no {stem.split('_AHA')[0]} values per AHA segment for this study"
    caption = (f"{subject}{', ' + frames if frames else ''}: {title} per AHA segment (1-6 basal, 7-12 mid, 13-16 apical; "
               "anterior up, septum left, seen from the apex). Grey hatched: no value.")
    label = stem.split("_AHA")[0].replace("WT", "Wall thickness")
    path = bullseye_figure(vals, title, unit, Path(out) / f"{name}.png", cmap=cmap,
                           diverging=diverging, caption=caption, label=label, canvas=canvas,
                           norm=fixed_norm(stem, diverging))
    return path, caption
