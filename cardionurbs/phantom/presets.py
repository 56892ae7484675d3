"""Pathology presets (package data ``cardionurbs/data/*.toml``), per-subject sampling and cohort specifications.

A preset TOML has three tables:

``[preset]``
    ``name``, ``description``.
``[sample]``
    Uniform ranges ``[lo, hi]`` drawn per subject from the seed: heart rate,
    LVEDV, LVEF, LVM, RV/LV mass ratio, twist, LS, EI at ES, ES timing, and
    shape ratios (``lv_long_short_ratio`` = r_long_endo / r_short_endo,
    ``base_height_ratio`` = base height / r_long_endo, ``apex_wall_ratio`` =
    apical / lateral LV wall thickness, ``rv_offset``, ``rv_wrap_ratio`` =
    r_wrap_endo / r_free_endo, ``rv_length_ratio`` = r_long_rv_endo / z_base,
    ``base_rotation_share`` = base share of the twist). The RV stroke volume
    conserves blood: either ``rvsv_over_lvsv`` and ``rvef_pct`` (no leak;
    RVEDV = RVSV / RVEF) or ``regurgitant_fraction_pct`` and ``rvedv_ml``
    (mitral regurgitation: RVSV = LVSV (1 − RF)).
``[targets]``
    Ranges ``[lo, hi]`` keyed by docs/metrics.md column that every subject's truth
    must satisfy. Sampling rejects draws whose predicted metrics fall outside
    them; the geometry is then solved so that the truth hits the draw exactly
    (LV size in closed form, wall thicknesses and RV size by Brent's method).

A cohort spec (``paper12.toml``) lists subjects: ``[cohort]`` (``name``,
optional defaults such as ``frames``) and ``[[subject]]`` entries with ``id``,
``pathology`` and ``seed`` (optionally ``frames``, ``noise_px``, ``tag_jumps``,
``breath_hold_mm``; each may also be a cohort-wide default in ``[cohort]``).
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from cardionurbs.errors import PhantomError
from cardionurbs.phantom.anatomy import Anatomy

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

PATHOLOGIES = ("normal", "mr", "phtn")
DENSITY = 1.05

_REQUIRED = ("heart_rate_bpm", "lvedv_ml", "lvef_pct", "lvm_g", "rv_lv_mass_ratio", "twist_deg",
             "ls_pct", "ei_es", "es_fraction", "lv_long_short_ratio", "base_height_ratio",
             "apex_wall_ratio", "rv_offset", "rv_wrap_ratio", "rv_length_ratio",
             "base_rotation_share")


def read_toml(path: str | Path) -> dict:
    """Parse a TOML file; PhantomError (one line, naming the file) if missing or malformed.

    Parameters
    ----------
    path : path-like
        A TOML file.

    Returns
    -------
    dict
        Its tables and values.

    Raises
    ------
    cardionurbs.errors.PhantomError
        Missing, a folder, malformed TOML, or not UTF-8.
    """
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise PhantomError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise PhantomError(f"{path}: is a directory, expected a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise PhantomError(f"{path}: malformed TOML ({exc})") from None
    except UnicodeDecodeError:
        raise PhantomError(f"{path}: not a UTF-8 text file") from None


def data_path(name: str) -> Path:
    """Path of a file shipped in cardionurbs/data (presets and the paper12 cohort).

    Parameters
    ----------
    name : str
        A file name in cardionurbs/data (``"normal.toml"``, ``"paper12.toml"``).

    Returns
    -------
    pathlib.Path
        Its path (not checked to exist).
    """
    return Path(str(resources.files("cardionurbs").joinpath("data", name)))


def load_preset(pathology: str | Path) -> dict:
    """A validated preset dict, by pathology name (packaged) or TOML path.

    Parameters
    ----------
    pathology : str or path-like
        ``"normal"``, ``"mr"``, ``"phtn"``, or the path of a preset ``.toml``.

    Returns
    -------
    dict
        The preset's ``[preset]``, ``[sample]`` (key -> [low, high]) and ``[targets]`` (metric
        column -> [low, high]) tables.

    Raises
    ------
    cardionurbs.errors.PhantomError
        An unknown pathology, or a file that is not a valid preset (naming file and key).
    """
    if isinstance(pathology, str) and pathology in PATHOLOGIES:
        path = data_path(f"{pathology}.toml")
    elif isinstance(pathology, (str, Path)) and str(pathology).endswith(".toml"):
        path = Path(pathology)
    else:
        raise PhantomError(f"unknown pathology {pathology!r}; expected one of {', '.join(PATHOLOGIES)}")
    d = read_toml(path)
    _validate_preset(d, path)
    return d


def _range(v, key: str, path) -> tuple[float, float]:
    if (not isinstance(v, list) or len(v) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
            or not v[0] <= v[1]):
        raise PhantomError(f"{path}: field {key} must be a range [lo, hi] of numbers with lo <= hi")
    return float(v[0]), float(v[1])


def _validate_preset(d: dict, path) -> None:
    for table in ("preset", "sample", "targets"):
        if not isinstance(d.get(table), dict):
            raise PhantomError(f"{path}: missing table [{table}]")
    s = d["sample"]
    for key in _REQUIRED:
        if key not in s:
            raise PhantomError(f"{path}: field sample.{key} is missing")
    modes = ("rvsv_over_lvsv" in s and "rvef_pct" in s, "regurgitant_fraction_pct" in s and "rvedv_ml" in s)
    if sum(modes) != 1:
        raise PhantomError(f"{path}: [sample] needs either rvsv_over_lvsv + rvef_pct or "
                           "regurgitant_fraction_pct + rvedv_ml")
    for key, v in s.items():
        lo, hi = _range(v, f"sample.{key}", path)
        if key.endswith(("_ml", "_g", "_bpm", "_ratio")) and lo <= 0:
            raise PhantomError(f"{path}: field sample.{key} must be positive")
    for key, v in d["targets"].items():
        _range(v, f"targets.{key}", path)


@dataclass(frozen=True)
class SubjectDraw:
    """Sampled physiological values of one subject (the preset's [sample] keys, derived values).

    Attributes
    ----------
    values : dict of str to float
        Sampled key -> value in its own unit (``lvedv_ml`` mL, ``lvef_pct`` %, ``lvm_g`` g,
        ``heart_rate_bpm`` beats/min, ``twist_deg`` deg, ratios dimensionless).
    """

    values: dict

    def predicted_metrics(self) -> dict:
        """The metrics the draw implies (what the anatomy is solved to reproduce).

        Returns
        -------
        dict of str to float
            docs/metrics.md column -> value (HR bpm, volumes mL, EF %, masses g, ratios,
            twist deg, LS %, EI ES).
        """
        v = self.values
        lvsv = v["lvedv_ml"] * v["lvef_pct"] / 100.0
        if "regurgitant_fraction_pct" in v:
            rvsv = lvsv * (1 - v["regurgitant_fraction_pct"] / 100.0)
            rvedv = v["rvedv_ml"]
        else:
            rvsv = lvsv * v["rvsv_over_lvsv"]
            rvedv = rvsv / (v["rvef_pct"] / 100.0)
        reg = max(0.0, lvsv - rvsv)
        return {"HR (bpm)": v["heart_rate_bpm"], "LVEDV (mL)": v["lvedv_ml"], "LVEF (%)": v["lvef_pct"],
                "LVSV (mL)": lvsv, "LVM (g)": v["lvm_g"], "RVEDV (mL)": rvedv, "RVSV (mL)": rvsv,
                "RVEF (%)": 100.0 * rvsv / rvedv, "MR RegVol (mL)": reg,
                "MR RegFrac (%)": 100.0 * reg / lvsv, "RV/LV EDV ratio": rvedv / v["lvedv_ml"],
                "RV/LV mass ratio": v["rv_lv_mass_ratio"], "RVM (g)": v["rv_lv_mass_ratio"] * v["lvm_g"],
                "Twist (deg)": v["twist_deg"], "LS (%)": v["ls_pct"], "EI ES": v["ei_es"]}


def in_targets(metrics: dict, targets: dict) -> list[str]:
    """Names of the target columns that ``metrics`` misses (NaN counts as a miss).

    Parameters
    ----------
    metrics : dict
        Metric column -> value (docs/metrics.md units).
    targets : dict
        Metric column -> (low, high) in the same units.

    Returns
    -------
    list of str
        The columns present in ``metrics`` whose value lies outside its target.
    """
    bad = []
    for key, (lo, hi) in targets.items():
        if key in metrics and not (lo <= metrics[key] <= hi):
            bad.append(key)
    return bad


def sample_subject(preset: dict, rng: np.random.Generator, max_tries: int = 5000) -> SubjectDraw:
    """Draw the [sample] ranges until the predicted metrics meet the [targets] (rejection).

    Parameters
    ----------
    preset : dict
        A preset (:func:`load_preset`).
    rng : numpy.random.Generator
        The subject's generator.
    max_tries : int, optional
        Draws before giving up.

    Returns
    -------
    SubjectDraw
        The first draw whose predicted metrics meet the targets.

    Raises
    ------
    cardionurbs.errors.PhantomError
        No draw meets the targets in ``max_tries``.
    """
    keys = sorted(preset["sample"])
    for _ in range(max_tries):
        vals = {k: float(rng.uniform(*preset["sample"][k])) for k in keys}
        draw = SubjectDraw(vals)
        if not in_targets(draw.predicted_metrics(), preset["targets"]):
            return draw
    raise PhantomError(f"preset {preset['preset'].get('name')!r}: the [sample] ranges cannot meet "
                       "the [targets] (no valid draw)")


def solve_anatomy(draw: SubjectDraw, shape=None) -> Anatomy:
    """ED anatomy that reproduces the drawn LVEDV, LVM, RVEDV and RV/LV mass ratio exactly.

    With realistic ``shape`` modes (:mod:`cardionurbs.phantom.shape`) the LV sizes are those of the
    ideal solution (the modes keep every section's area) and the RV size and wall are solved again
    on the realistic RV (its modes change the crescent's area); an infarct's thinning then lowers
    the LV mass below the draw, as it would in a patient.

    Parameters
    ----------
    draw : SubjectDraw
        The subject's values.
    shape : cardionurbs.phantom.shape.ShapeModes, optional
        Realistic shape modes (None: the ideal spheroids).

    Returns
    -------
    cardionurbs.phantom.anatomy.Anatomy
        The ED anatomy (mm).
    """
    v = draw.values
    pm = draw.predicted_metrics()
    rho, eta, k = v["lv_long_short_ratio"], v["base_height_ratio"], v["apex_wall_ratio"]
    vol = v["lvedv_ml"] * 1000.0
    v_myo = v["lvm_g"] / DENSITY * 1000.0
    outflow = getattr(shape, "outflow", None)

    def lv_sizes(vol_body: float) -> tuple[float, float, float, float]:
        a = (vol_body / (np.pi * rho * (2.0 / 3.0 + eta - eta ** 3 / 3.0))) ** (1.0 / 3.0)
        c, h = rho * a, eta * rho * a
        t = brentq(lambda t: _lv_anatomy(a, c, h, k, t).lv_myocardial_volume() - v_myo, 0.5, 0.9 * a,
                   xtol=1e-10)
        return a, c, h, t

    a, c, h, t = lv_sizes(vol)
    if outflow is not None:
        # the LVOT lumen counts in the LV volume: the body is solved for the rest (a fixed point,
        # the LVOT scaling with the LV)
        from cardionurbs.phantom.truth_realistic import ed_outflow_volumes
        for _ in range(3):
            probe = dataclasses.replace(_lv_anatomy(a, c, h, k, t), shape=shape)
            extra = ed_outflow_volumes(probe, ("lv",), 0.5, 64, exact_planes=False)["lv_endo"] * 1000.0
            a, c, h, t = lv_sizes(vol - extra)

    def lv(t: float, **rv) -> Anatomy:
        return _lv_anatomy(a, c, h, k, t, **rv)

    zb = lv(t).z_base
    q, beta, ell = v["rv_offset"], v["rv_wrap_ratio"], v["rv_length_ratio"]

    def rv(A: float, wall: float = 3.0) -> Anatomy:
        return lv(t, r_free_endo=A, r_wrap_endo=beta * A, r_long_rv_endo=ell * zb, rv_wall=wall,
                  rv_offset=q)

    rvedv = pm["RVEDV (mL)"] * 1000.0
    a_min = 1.02 * (a + t) / (1 + q)
    try:
        A = brentq(lambda A: rv(A).rv_cavity_volume() - rvedv, a_min, 4 * (a + t), xtol=1e-10)
        rvm = pm["RVM (g)"] / DENSITY * 1000.0
        wall = brentq(lambda w: rv(A, w).rv_myocardial_volume() - rvm, 0.3, 20.0, xtol=1e-10)
    except ValueError:
        raise PhantomError("RV volume or mass cannot be reached with these shape ratios") from None
    if shape is None:
        return rv(A, wall).validate()

    def rv_real(A2: float, wall2: float) -> Anatomy:
        return dataclasses.replace(rv(A2, wall2), shape=shape)

    @functools.lru_cache(maxsize=8)
    def tract_volumes(an: Anatomy) -> dict:
        from cardionurbs.phantom.truth_realistic import ed_outflow_volumes
        return ed_outflow_volumes(an, ("rv",), 0.5, 64, exact_planes=False)

    def tract(an: Anatomy, key: str) -> float:
        """The RVOT's ED lumen (rv_endo) or lumen and wall (rv_epi), mm³ (0 without one)."""
        return 0.0 if outflow is None else tract_volumes(an)[key] * 1000.0

    @functools.lru_cache(maxsize=8)
    def cap(an: Anatomy) -> dict:
        """The tricuspid closure's change to the body volumes (a dipping annulus closes the RV at
        its best-fit plane, below the base plane)."""
        from cardionurbs.phantom.truth_realistic import ed_tricuspid_correction
        return ed_tricuspid_correction(an)

    def rv_cavity(an: Anatomy) -> float:
        return an.rv_shell_volume(False, 96, 48) + tract(an, "rv_endo") + cap(an)["rv_endo"]

    def rv_muscle(an: Anatomy) -> float:
        return (an.rv_shell_volume(True, 96, 48) + tract(an, "rv_epi") + cap(an)["rv_epi"]
                - rv_cavity(an))

    try:
        # quadrature orders well inside the 0.2 % truth budget (the truth is computed anew)
        lo_a = 0.6 if outflow is not None else 0.8
        A = brentq(lambda x: rv_cavity(rv_real(x, wall)) - rvedv, lo_a * A, 1.25 * A, xtol=1e-3)
        wall = brentq(lambda w: rv_muscle(rv_real(A, w)) - rvm, 0.5 * wall, 2.0 * wall, xtol=1e-3)
    except ValueError:
        raise PhantomError("the realistic RV cannot reach the drawn RV volume or mass") from None
    return rv_real(A, wall).validate()


def _lv_anatomy(a: float, c: float, h: float, k: float, t: float, **rv) -> Anatomy:
    """The LV sizes (endocardial semi-axes a, c, base height h, wall t, apical ratio k) with
    placeholder RV sizes unless given."""
    base = dict(r_free_endo=a, r_wrap_endo=a, r_long_rv_endo=0.5 * c, rv_wall=3.0, rv_offset=0.5)
    base.update(rv)
    return Anatomy(r_short_endo=a, r_short_epi=a + t, r_long_endo=c, r_long_epi=c + k * t,
                   base_height=h, **base)


# ----------------------------------------------------------------- cohorts
_SUBJECT_OPTIONS = ("frames", "noise_px", "tag_jumps", "breath_hold_mm")


@dataclass(frozen=True)
class SubjectSpec:
    """One subject of a cohort spec.

    Attributes
    ----------
    id : str
        The subject id (its folder name).
    pathology : str
        ``"normal"``, ``"mr"`` or ``"phtn"``.
    seed : int
        The subject's seed.
    frames : int
        Frames per cycle.
    noise_px : float
        Contour and tag noise σ, in pixels.
    tag_jumps : int
        Tag jumps injected.
    breath_hold_mm : float
        Breath-hold slice shift σ, in mm.
    """

    id: str
    pathology: str
    seed: int
    frames: int = 20
    noise_px: float = 0.0
    tag_jumps: int = 0
    breath_hold_mm: float = 0.0


def load_cohort_spec(path: str | Path) -> list[SubjectSpec]:
    """Subjects of a cohort TOML (``[cohort]`` defaults + ``[[subject]]`` entries).

    Parameters
    ----------
    path : path-like
        A cohort TOML.

    Returns
    -------
    list of SubjectSpec
        The subjects, in file order.

    Raises
    ------
    cardionurbs.errors.PhantomError
        No ``[[subject]]``, a missing or bad field, or a repeated or unsafe id (naming the file
        and the subject).
    """
    path = Path(path)
    d = read_toml(path)
    subjects = d.get("subject")
    if not isinstance(subjects, list) or not subjects:
        raise PhantomError(f"{path}: needs at least one [[subject]] entry")
    defaults = d.get("cohort", {})
    if not isinstance(defaults, dict):
        raise PhantomError(f"{path}: [cohort] must be a table")
    out, seen = [], set()
    for i, s in enumerate(subjects):
        if not isinstance(s, dict):
            raise PhantomError(f"{path}: subject {i + 1} must be a table")
        merged = {k: defaults[k] for k in _SUBJECT_OPTIONS if k in defaults}
        merged.update(s)
        for key in ("id", "pathology", "seed"):
            if key not in merged:
                raise PhantomError(f"{path}: subject {i + 1}: field {key} is missing")
        sid = str(merged["id"])
        if not sid or "/" in sid or sid.startswith(".") or sid in seen:
            raise PhantomError(f"{path}: subject {i + 1}: id {sid!r} is empty, not a folder name or repeated")
        seen.add(sid)
        if merged["pathology"] not in PATHOLOGIES:
            raise PhantomError(f"{path}: subject {sid}: unknown pathology {merged['pathology']!r}")
        try:
            spec = SubjectSpec(id=sid, pathology=str(merged["pathology"]), seed=int(merged["seed"]),
                               frames=int(merged.get("frames", 20)),
                               noise_px=float(merged.get("noise_px", 0.0)),
                               tag_jumps=int(merged.get("tag_jumps", 0)),
                               breath_hold_mm=float(merged.get("breath_hold_mm", 0.0)))
        except (TypeError, ValueError):
            raise PhantomError(f"{path}: subject {sid}: seed, frames, noise_px, tag_jumps and "
                               "breath_hold_mm must be numbers") from None
        unknown = set(merged) - {"id", "pathology", "seed", *_SUBJECT_OPTIONS}
        if unknown:
            raise PhantomError(f"{path}: subject {sid}: unknown field {sorted(unknown)[0]}")
        out.append(spec)
    return out
