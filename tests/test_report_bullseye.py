"""AHA bull's-eye (cardionurbs.report.bullseye): each segment's wedge sits where the layout
puts it and shows its own value's colour; a segment without a value is hatched grey."""

from __future__ import annotations

import math

import matplotlib
import pytest
from matplotlib.figure import Figure

from cardionurbs.report.bullseye import QUANTITIES, draw_bullseye, quantity_figure, segment_wedges


def test_segments_are_placed_and_coloured_by_their_values():
    values = {k: float(k) for k in range(1, 18)}
    values[5] = math.nan
    ax = Figure().add_subplot(projection="polar")
    norm = draw_bullseye(ax, values, cmap="viridis")
    wedges = segment_wedges()
    assert len(ax.patches) == len(wedges) == 17
    cmap = matplotlib.colormaps["viridis"]
    for (k, (a0, w, r0, r1)), p in zip(wedges.items(), ax.patches):
        assert (p.get_x(), p.get_width(), p.get_y(), p.get_height()) == pytest.approx(
            (a0, w, r0, r1 - r0)), k
        if k == 5:
            assert p.get_hatch() == "//"
            assert p.get_facecolor() == pytest.approx(matplotlib.colors.to_rgba("#dddddd"))
        else:
            assert not p.get_hatch()
            assert p.get_facecolor() == pytest.approx(cmap(norm(values[k])))
    labels = [t.get_text() for t in ax.texts]
    assert labels[list(wedges).index(5)] == "5\n–" and "17\n17.0" in labels
    assert (norm.vmin, norm.vmax) == (1.0, 17.0)        # the finite values' range


def test_quantity_figure_writes_png_or_says_why(tmp_path):
    q = next(q for q in QUANTITIES if q[0] == "fig15_bullseye_ecc")
    metrics = {f"Ecc_AHA_{k} (%)": -10.0 - k for k in range(1, 17)}
    path, caption = quantity_figure(metrics, q, "s1", tmp_path, frames="ED frame 0, ES frame 7")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and "s1, ED frame 0" in caption
    assert "no Ecc values" in quantity_figure({}, q, "s1", tmp_path)


def test_colour_scales_are_fixed_per_quantity_and_stated(tmp_path, monkeypatch):
    """The same thickness gets the same colour whatever the other segments hold (a fixed
    scale, not the data's range), and the colour bar says the scale."""
    import numpy as np
    from cardionurbs.report import bullseye as B
    norm = B.fixed_norm("WT_AHA_{k} (mm)", False)
    assert (norm.vmin, norm.vmax) == B.SCALES["WT"] == (0.0, 20.0)
    ecc = B.fixed_norm("Ecc_AHA_{k} (%)", True)
    assert ecc(0.0) == pytest.approx(0.5) and ecc(-30.0) == pytest.approx(0.0)
    labels = []
    orig = Figure.colorbar

    def spy(self, mappable, *a, **k):
        labels.append(k.get("label"))
        return orig(self, mappable, *a, **k)
    monkeypatch.setattr(Figure, "colorbar", spy)
    faces = []
    for spread in (1.0, 6.0):       # the others 6-8 mm, then 6-18 mm: a data-range scale
        vals = {k: 6.0 + spread * (k % 3) for k in range(1, 17)}      # would recolour 8 mm
        vals[1] = 8.0
        metrics = {f"WT_AHA_{k} (mm)": v for k, v in vals.items()}
        _, face, *_ = B._segment_style(vals, "viridis", norm, "{:.1f}")
        faces.append(matplotlib.colors.to_rgba(face[list(segment_wedges()).index(1)]))
        assert not isinstance(quantity_figure(metrics, QUANTITIES[0], "s", tmp_path), str)
    assert np.allclose(faces[0], faces[1])        # segment 1 holds 8.0 mm both times
    assert all("fixed scale 0 to 20 mm" in lab for lab in labels)
