"""Phantom presets: target ranges for every subject, blood conservation, paper12, bad specs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cardionurbs.errors import PhantomError
from cardionurbs.phantom import generate, load_cohort_spec, load_preset
from cardionurbs.phantom.presets import in_targets, read_toml

ROOT = Path(__file__).resolve().parents[1]


def _truth(pathology, seed):
    # truth metrics only depend on the ED and ES phases: 2 frames is enough and fast
    return generate(pathology, seed=seed, frames=2, volume_check=False).truth["metrics"]


@pytest.mark.parametrize("pathology", ["normal", "mr", "phtn"])
def test_every_seed_meets_targets_and_conserves_blood(pathology):
    targets = load_preset(pathology)["targets"]
    for seed in range(6):
        m = _truth(pathology, seed)
        assert not in_targets(m, targets), (pathology, seed, in_targets(m, targets))
        if pathology == "mr":
            assert m["RVSV (mL)"] == pytest.approx(m["LVSV (mL)"] - m["MR RegVol (mL)"], rel=1e-12)
            assert 30 <= m["MR RegFrac (%)"] <= 50
        else:
            assert abs(m["LVSV (mL)"] - m["RVSV (mL)"]) / m["LVSV (mL)"] <= 0.05


def test_issue_target_ranges_hold():
    """The issue's ranges, written out independently of the TOML files."""
    n = _truth("normal", 11)
    assert 140 <= n["LVEDV (mL)"] <= 160 and 60 <= n["LVEF (%)"] <= 67 and 100 <= n["LVM (g)"] <= 135
    assert 150 <= n["RVEDV (mL)"] <= 190 and 55 <= n["RVEF (%)"] <= 60
    assert 10 <= n["Twist (deg)"] <= 15 and 12 <= n["LS (%)"] <= 18
    mr = _truth("mr", 11)
    assert mr["LVEDV (mL)"] >= 200 and mr["LVEF (%)"] >= 65 and 30 <= mr["MR RegFrac (%)"] <= 50
    p = _truth("phtn", 11)
    assert p["RV/LV EDV ratio"] >= 1.5 and p["RV/LV mass ratio"] >= 0.45 and p["RVEF (%)"] <= 40
    assert p["EI ES"] >= 1.3 and p["Twist (deg)"] < n["Twist (deg)"]
    assert p["LVEDV (mL)"] < n["LVEDV (mL)"]


def test_paper12_composition_and_targets():
    subjects = load_cohort_spec(ROOT / "phantoms" / "paper12.toml")
    counts = {p: sum(s.pathology == p for s in subjects) for p in ("normal", "mr", "phtn")}
    assert counts == {"normal": 5, "mr": 3, "phtn": 4}
    assert len({s.id for s in subjects}) == 12 and all(s.frames == 20 for s in subjects)
    for s in subjects:
        assert not in_targets(_truth(s.pathology, s.seed), load_preset(s.pathology)["targets"])


def test_phantoms_folder_links_to_the_package_data():
    """One source for the presets (docs/formats.md): phantoms/*.toml are links to
    cardionurbs/data/*.toml, never copies that could drift apart."""
    data = ROOT / "cardionurbs" / "data"
    for toml in sorted((ROOT / "phantoms").glob("*.toml")):
        assert toml.is_symlink(), f"{toml} is a copy, not a link to {data}"
        assert toml.resolve() == (data / toml.name).resolve()
    assert sorted(p.name for p in (ROOT / "phantoms").glob("*.toml")) == \
        sorted(p.name for p in data.glob("*.toml"))


@pytest.mark.parametrize("text, word", [
    ("[preset]\nname = 'x'\n[sample\n", "malformed TOML"),
    ("[preset]\nname = 'x'\n", "[sample]"),
])
def test_malformed_preset_is_one_line(tmp_path, text, word):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(PhantomError) as e:
        load_preset(str(p))
    assert word in str(e.value) and str(p) in str(e.value) and "\n" not in str(e.value)


def test_preset_range_must_be_ordered(tmp_path):
    text = (ROOT / "phantoms" / "normal.toml").read_text().replace("lvedv_ml = [141.0, 159.0]",
                                                                    "lvedv_ml = [159.0, 141.0]")
    p = tmp_path / "n.toml"
    p.write_text(text)
    with pytest.raises(PhantomError, match="sample.lvedv_ml"):
        load_preset(str(p))


def test_missing_toml_and_bad_cohort(tmp_path):
    with pytest.raises(PhantomError, match="file not found"):
        read_toml(tmp_path / "nope.toml")
    bad = tmp_path / "c.toml"
    bad.write_text("[[subject]]\nid = 'a'\npathology = 'flu'\nseed = 1\n")
    with pytest.raises(PhantomError, match="unknown pathology"):
        load_cohort_spec(bad)
    bad.write_text("[[subject]]\nid = 'a'\npathology = 'mr'\nseed = 1\n[[subject]]\nid = 'a'\n"
                   "pathology = 'mr'\nseed = 2\n")
    with pytest.raises(PhantomError, match="repeated"):
        load_cohort_spec(bad)


@pytest.mark.parametrize("kw, word", [
    (dict(pathology="flu"), "unknown pathology"),
    (dict(frames=1), "frames"),
    (dict(seed=-1), "seed"),
    (dict(noise_px=-0.5), "noise_px"),
    (dict(tag_jumps=-2), "tag_jumps"),
    (dict(sa_spacing_mm=-10.0), "sa_spacing_mm"),
])
def test_bad_generate_arguments(kw, word):
    with pytest.raises(PhantomError) as e:
        generate(**{"frames": 2, **kw})
    assert word in str(e.value) and "\n" not in str(e.value)


def test_seeds_vary_subjects():
    a, b = _truth("normal", 1), _truth("normal", 2)
    assert a["LVEDV (mL)"] != b["LVEDV (mL)"] and np.isfinite(a["Twist 2D (deg)"])


@pytest.mark.parametrize("over, word", [
    ({"r_short_endo": -3.0}, "r_short_endo must be a positive"),
    ({"r_short_endo": 60.0}, "wall thickness"),
    ({"r_long_endo": 200.0}, "r_long_epi must exceed"),
    ({"radius": 3.0}, "unknown anatomy parameter"),
])
def test_bad_anatomy_overrides(over, word):
    with pytest.raises(PhantomError) as e:
        generate("normal", frames=2, anatomy=over)
    assert word in str(e.value) and "\n" not in str(e.value)


def test_anatomy_override_changes_truth():
    base = generate("normal", seed=0, frames=2, volume_check=False)
    a = dict(base.truth["anatomy"])
    bigger = generate("normal", seed=0, frames=2, anatomy={"r_short_endo": a["r_short_endo"] + 1.0})
    assert bigger.truth["metrics"]["LVEDV (mL)"] > base.truth["metrics"]["LVEDV (mL)"]
    assert bigger.truth["metrics"]["LVM (g)"] < base.truth["metrics"]["LVM (g)"]
    assert bigger.truth["volumes"]["max_relative_difference"] < 0.002


@settings(max_examples=15, deadline=None)
@given(pathology=st.sampled_from(["normal", "mr", "phtn"]), seed=st.integers(0, 10 ** 6))
def test_solved_anatomy_reproduces_the_draw(pathology, seed):
    from cardionurbs.phantom.presets import sample_subject, solve_anatomy
    draw = sample_subject(load_preset(pathology), np.random.default_rng(seed))
    a = solve_anatomy(draw)
    pm = draw.predicted_metrics()
    assert a.lv_cavity_volume() / 1000 == pytest.approx(pm["LVEDV (mL)"], rel=1e-9)
    assert 1.05 * a.lv_myocardial_volume() / 1000 == pytest.approx(pm["LVM (g)"], rel=1e-9)
    assert a.rv_cavity_volume() / 1000 == pytest.approx(pm["RVEDV (mL)"], rel=1e-9)
    assert 1.05 * a.rv_myocardial_volume() / 1000 == pytest.approx(pm["RVM (g)"], rel=1e-9)
    # the RV crescent edge solves g² P(θ_e) = s_epi on every section that has one
    z = np.linspace(a.z_base - a.r_long_rv_endo, a.z_base, 60)
    e = a.rv_sector_edge(z)
    has = (e > 0) & (e < np.pi)
    np.testing.assert_allclose(a.rv_g2(z[has]) * a.rv_p(e[has]), a.s_lv_epi(z[has]), rtol=1e-10)


def test_cohort_options_and_defaults(tmp_path):
    spec = tmp_path / "c.toml"
    spec.write_text("[cohort]\nframes = 4\nnoise_px = 0.3\n[[subject]]\nid = 'a'\npathology = 'mr'\n"
                    "seed = 1\nbreath_hold_mm = 1.5\n[[subject]]\nid = 'b'\npathology = 'phtn'\n"
                    "seed = 2\nframes = 6\ntag_jumps = 2\n")
    a, b = load_cohort_spec(spec)
    assert (a.frames, a.noise_px, a.breath_hold_mm, a.tag_jumps) == (4, 0.3, 1.5, 0)
    assert (b.frames, b.noise_px, b.breath_hold_mm, b.tag_jumps) == (6, 0.3, 0.0, 2)
    spec.write_text("[[subject]]\nid = 'a'\npathology = 'mr'\nseed = 1\ncolour = 'red'\n")
    with pytest.raises(PhantomError, match="unknown field colour"):
        load_cohort_spec(spec)
    spec.write_text("[[subject]]\nid = 'a'\npathology = 'mr'\nseed = 'one'\n")
    with pytest.raises(PhantomError, match="must be numbers"):
        load_cohort_spec(spec)
