"""Static figures (paper Figs. 3-10, volume/twist curves) for a phantom and real studies, headless."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from PIL import Image

from cardionurbs.report import figures as F
from conftest import shared_data


def colour_pixels(img: np.ndarray, hex_colour: str) -> np.ndarray:
    """Mask of pixels whose RGB is the colour scaled by a shading factor in [0.4, 1.05]
    (the figures' Lambert shading keeps the hue: cosine > 0.998, relative error < 6 %)."""
    c = np.asarray(F._rgb(hex_colour))
    rgb = img[..., :3].astype(float) / 255.0
    k = (rgb @ c) / (c @ c)                                    # best scale factor per pixel
    resid = np.linalg.norm(rgb - k[..., None] * c, axis=-1)
    return (k > 0.4) & (k < 1.05) & (resid < 0.06 * np.linalg.norm(c) + 0.01)


def check_png(res: F.FigureResult, *, min_fg: float = 0.02, max_fg: float = 0.7,
              min_pixels: int = 60, caption_word: str = "frame") -> None:
    """Not blank: a sensible foreground fraction, and every listed colour drawn outside
    the legend (legend boxes are masked out, so a patch alone does not pass)."""
    img = np.asarray(Image.open(res.path).convert("RGB"))
    assert img.shape[0] > 300 and img.shape[1] > 400
    fg = (np.abs(img.astype(int) - 255).max(axis=-1) > 25).mean()
    assert min_fg < fg < max_fg, f"{res.name}: foreground fraction {fg:.3f}"
    mask = np.ones(img.shape[:2], bool)
    for x0, y0, x1, y1 in res.legend_boxes:
        mask[max(int(y0) - 2, 0):int(y1) + 3, max(int(x0) - 2, 0):int(x1) + 3] = False
    for label, colour in res.colours.items():
        n = int((colour_pixels(img, colour) & mask).sum())
        assert n >= min_pixels, f"{res.name}: colour of {label} ({colour}) on {n} pixels"
    assert caption_word in res.caption.lower()


# --------------------------------------------------------------- phantom
@pytest.fixture(scope="module")
def phantom_figures(tmp_path_factory):
    from cardionurbs import reconstruct
    from cardionurbs.phantom import generate
    ph = generate("normal", seed=3, frames=3, tag_jumps=2, volume_check=False)
    model = reconstruct(ph.study)
    out = tmp_path_factory.mktemp("phantom_figs")
    return model, F.render_figures(model, out, truth=ph.truth), out


def test_phantom_every_figure_is_drawn(phantom_figures):
    model, fs, out = phantom_figures
    assert fs.skipped == {}
    assert [f.name for f in fs.figures] == list(F.FIGURES)
    for res in fs.figures:
        check_png(res)
        assert model.study.subject in res.caption
    idx = json.loads((out / "figures.json").read_text())
    assert [f["file"] for f in idx["figures"]] == [p.name for p in fs.paths]
    assert (out / "skipped.txt").read_text() == ""


def test_phantom_tag_qc_figure_shows_flagged_lines(phantom_figures):
    model, fs, out = phantom_figures
    fig8 = next(f for f in fs.figures if f.name == "fig08_tag_qc")
    assert "flagged line" in fig8.colours          # the phantom has two tag jumps
    tags = json.loads((out / "report_tags.json").read_text())
    assert tags["flags"] and set(tags["frames"]) == {str(f) for f in model.study.tagged_frames}


def test_structure_colours_are_okabe_ito_and_distinct():
    cols = list(F.STRUCTURE_COLOURS.values()) + list(F.FAMILY_COLOURS.values())
    assert set(cols) <= set(F.OKABE_ITO.values()) and len(set(cols)) == len(cols)


def test_colour_check_rejects_a_blank_or_wrong_image(tmp_path):
    """The pixel test itself can fail: a white image, or another structure's colour."""
    white = tmp_path / "white.png"
    Image.new("RGB", (640, 480), "white").save(white)
    with pytest.raises(AssertionError):
        check_png(F.FigureResult("x", white, "frame 0", {"lv_endo": F.STRUCTURE_COLOURS["lv_endo"]}))
    blue = tmp_path / "blue.png"
    a = np.full((480, 640, 3), 255, np.uint8)
    a[100:300, 100:400] = (np.array(F._rgb(F.STRUCTURE_COLOURS["rv_endo"])) * 255 * 0.8).astype(np.uint8)
    Image.fromarray(a).save(blue)
    check_png(F.FigureResult("x", blue, "frame 0", {"rv": F.STRUCTURE_COLOURS["rv_endo"]}))
    with pytest.raises(AssertionError):
        check_png(F.FigureResult("x", blue, "frame 0", {"lv": F.STRUCTURE_COLOURS["lv_endo"]}))


unit3 = arrays(np.float64, 3, elements=st.floats(-1, 1)).filter(lambda v: np.linalg.norm(v) > 0.1)


@settings(max_examples=30, deadline=None)
@given(arrays(np.float64, 3, elements=st.floats(-100, 100)), unit3, unit3)
@example(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))     # eye straight down z
@example(np.zeros(3), np.array([0, 0, 1.0]), np.array([0, 0, 1.0]))     # side along the axis
@example(np.zeros(3), np.array([0, 1.0, 0]), np.array([1.0, 0, 0]))     # eye straight up z
def test_view_puts_base_up_and_rv_beside_lv(apex, axis_dir, side):
    """Camera: the long axis projects vertical (base up) on screen for any axis direction,
    and the eye looks perpendicular to both the axis and the septal direction."""
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d import proj3d
    base = apex + 80 * F._unit(axis_dir)
    w, up = F.view_frame((apex, base), side)
    assert abs(w @ up) < 1e-9 and np.linalg.norm(w) == pytest.approx(1.0)
    s_perp = side - (side @ up) * up
    if np.linalg.norm(s_perp) > 1e-3:
        assert abs(w @ s_perp) < 1e-9 * max(1.0, np.linalg.norm(s_perp))
    v = F._camera(w, up, (apex + base) / 2, 60.0)
    ax = Figure().add_subplot(projection="3d")
    c, h = v.centre, v.half
    ax.set_xlim(c[0] - h, c[0] + h), ax.set_ylim(c[1] - h, c[1] + h)
    ax.set_zlim(c[2] - h, c[2] + h), ax.set_box_aspect((1, 1, 1))
    ax.view_init(v.elev, v.azim, v.roll)
    M = ax.get_proj()
    xa, ya, _ = proj3d.proj_transform(*apex, M)
    xb, yb, _ = proj3d.proj_transform(*base, M)
    assert yb > ya and abs(xb - xa) < 1e-6 + 0.02 * abs(yb - ya)


# --------------------------------------------------------------- real data
def _real(path, frames=None):
    import cardionurbs as cn
    study = cn.load_study(path)
    return cn.reconstruct(study, frames=frames) if frames else cn.reconstruct(study)


def test_sunnybrook_figures_and_one_line_skips(tmp_path):
    """Sunnybrook: LV only, 2 frames, no tags: RV, tag and curve figures are left out
    with one line each (the biventricular figure too: no RV); LV figures are drawn."""
    model = _real(shared_data("sunnybrook", "SC-HF-I-1"))
    fs = F.render_figures(model, tmp_path)
    drawn = {f.name for f in fs.figures}
    assert {"fig03_lv_endo_ed_es", "fig04_lv_endo_epi"} <= drawn
    assert "rv_endo" in fs.skipped["fig10_biventricular_tags"]
    assert set(fs.skipped) == set(F.FIGURES) - drawn
    assert "rv_endo" in fs.skipped["fig05_rv_endo_ed_es"]
    assert "no tag lines" in fs.skipped["fig09_all_tag_surfaces"]
    assert "at least 3" in fs.skipped["fig11_volume_time"]
    lines = (tmp_path / "skipped.txt").read_text().splitlines()
    assert len(lines) == len(fs.skipped) and all(": " in ln for ln in lines)
    for res in fs.figures:
        check_png(res)


def test_cap_biventricular_figures(tmp_path):
    """CAP (bivme patient 1), three frames: LV, RV, biventricular and volume–time."""
    model = _real(shared_data("bivme-patient1"), frames=[0, 10, 20])
    fs = F.render_figures(model, tmp_path, only=["fig03_lv_endo_ed_es", "fig05_rv_endo_ed_es",
                                                 "fig06_rv_with_lv", "fig10_biventricular_tags",
                                                 "fig11_volume_time", "fig09_all_tag_surfaces"])
    assert [f.name for f in fs.figures] == ["fig03_lv_endo_ed_es", "fig05_rv_endo_ed_es",
                                            "fig06_rv_with_lv", "fig10_biventricular_tags",
                                            "fig11_volume_time"]
    assert set(fs.skipped) == {"fig09_all_tag_surfaces"}
    for res in fs.figures:
        check_png(res)


def test_one_frame_model_leaves_out_pairs_without_crashing(tmp_path):
    import cardionurbs as cn
    from cardionurbs.phantom import generate
    ph = generate("mr", seed=2, frames=2, volume_check=False)
    ph.study.tags = []
    model = cn.reconstruct(ph.study, frames=[0])
    fs = F.render_figures(model, tmp_path, only=["fig03_lv_endo_ed_es", "fig07_tag_surface_ed_es",
                                                 "fig11_volume_time", "fig12_twist_time"])
    assert [f.name for f in fs.figures] == ["fig03_lv_endo_ed_es"]
    assert "one frame" in fs.figures[0].caption.lower() or "only one" in fs.figures[0].caption
    assert set(fs.skipped) == {"fig07_tag_surface_ed_es", "fig11_volume_time", "fig12_twist_time"}
    check_png(fs.figures[0])
