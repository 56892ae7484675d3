"""Every figure, drawn for a phantom, a Sunnybrook patient and bivme-patient1, has no two
text boxes overlapping (captions, titles, tick and axis labels, legends, bull's-eye labels)
and no legend entry without a drawn artist (issue 32)."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.text import Text

import cardionurbs as cn
from cardionurbs.report import figures as F

from conftest import shared_data


class TextRecorder:
    """Records the window box of every text drawn into a figure, per saved PNG, and the
    axes legends' entries with whether their artist has finite data."""

    def __init__(self, monkeypatch) -> None:
        self.drawn: dict[int, list] = defaultdict(list)
        self.saved: dict[str, dict] = {}
        text_draw, savefig = Text.draw, Figure.savefig
        rec = self

        def draw(self, renderer):
            text_draw(self, renderer)
            if self.get_visible() and self.get_text().strip() and renderer is not None:
                fig = self.get_figure(root=True) if hasattr(self, "get_figure") else self.figure
                e = self.get_window_extent(renderer)
                rec.drawn[id(fig)].append((e.x0, e.y0, e.x1, e.y1, self.get_text()))

        def save(self, fname, *a, **k):
            rec.drawn[id(self)] = []
            out = savefig(self, fname, *a, **k)
            entries = []
            for ax in self.axes:
                if ax.get_legend() is None:
                    continue
                for h, lab in zip(*ax.get_legend_handles_labels()):
                    y = h.get_ydata() if hasattr(h, "get_ydata") else [0.0]
                    entries.append((lab, bool(np.isfinite(np.asarray(y, float)).any())))
            w, h = self.get_figwidth() * self.dpi, self.get_figheight() * self.dpi
            rec.saved[str(fname)] = {"texts": list(rec.drawn[id(self)]), "legend": entries,
                                     "size": (w, h)}
            return out

        monkeypatch.setattr(Text, "draw", draw)
        monkeypatch.setattr(Figure, "savefig", save)


def overlaps(boxes: list, tol_px: float = 1.0) -> list[tuple[str, str]]:
    """Pairs of texts whose boxes overlap by more than ``tol_px`` in both directions."""
    b = np.array([x[:4] for x in boxes], float).reshape(-1, 4)
    out = []
    for i in range(len(b)):
        dx = np.minimum(b[i, 2], b[i + 1:, 2]) - np.maximum(b[i, 0], b[i + 1:, 0])
        dy = np.minimum(b[i, 3], b[i + 1:, 3]) - np.maximum(b[i, 1], b[i + 1:, 1])
        for j in np.flatnonzero((dx > tol_px) & (dy > tol_px)):
            out.append((boxes[i][4], boxes[i + 1 + j][4]))
    return out


def outside(got: dict, tol_px: float = 1.0) -> list[str]:
    """Texts reaching beyond the figure (cut off in the PNG)."""
    w, h = got["size"]
    return [t for x0, y0, x1, y1, t in got["texts"]
            if x0 < -tol_px or y0 < -tol_px or x1 > w + tol_px or y1 > h + tol_px]


def check_recorded(rec: "TextRecorder") -> None:
    """No overlapping or cut-off text and no legend entry without drawn data, in every
    recorded figure."""
    for key, got in rec.saved.items():
        assert overlaps(got["texts"]) == [], (key, overlaps(got["texts"])[:3])
        assert outside(got) == [], (key, outside(got)[:3])
        assert all(ok for _, ok in got["legend"]), (key, got["legend"])


def test_overlap_check_can_fail():
    boxes = [(0, 0, 10, 10, "a"), (5, 5, 15, 15, "b"), (20, 0, 30, 10, "c")]
    assert overlaps(boxes) == [("a", "b")]


def test_phantom_figures_have_no_overlapping_text(tmp_path, monkeypatch):
    from cardionurbs.phantom import generate
    from cardionurbs.pipeline import analyse
    ph = generate("normal", seed=0, frames=3, volume_check=False)
    model, metrics, tags = analyse(ph.study)
    rec = TextRecorder(monkeypatch)
    fs = F.render_figures(model, tmp_path, metrics=metrics, truth=ph.truth, tags=tags, jobs=1)
    assert len(rec.saved) >= len(fs.figures) >= 10
    check_recorded(rec)


@pytest.mark.parametrize("subject, frames", [(("sunnybrook", "SC-HF-I-1"), None),
                                             (("bivme-patient1",), [0, 10, 20])])
def test_real_study_figures_have_no_overlapping_text(subject, frames, tmp_path, monkeypatch):
    study = cn.load_study(shared_data(*subject))
    model = cn.reconstruct(study, frames=frames) if frames else cn.reconstruct(study)
    rec = TextRecorder(monkeypatch)
    fs = F.render_figures(model, tmp_path, jobs=1)
    assert len(rec.saved) >= len(fs.figures) >= 2
    check_recorded(rec)
