"""Voxel counting beside the model: the volumes and mass a label map gives by counting.

This is what ukbb_cardiac and most segmentation pipelines report: a
structure's volume is its number of voxels times the voxel volume (in-plane
pixel area times the slice spacing), i.e. Simpson's disks with the slice
positions of the stack. The counts per frame come from the reader
(``study.meta["voxel_volumes_ml"]``, :func:`cardionurbs.io.nifti.voxel_volumes`);
here they are read at the model's ED and ES frames so that both methods
measure the same phases. Columns (mL, %, g; density 1.05 g/mL as for the model)::

    LVEDV voxel (mL), LVESV voxel (mL), LVEF voxel (%),
    RVEDV voxel (mL), RVESV voxel (mL), RVEF voxel (%), LVM voxel (g)

LVM voxel is the ED myocardium count times 1.05 g/mL. NaN where the label
map lacks the frame or the structure.
"""

from __future__ import annotations

import math
from typing import TypeGuard

from cardionurbs.analysis.function import NAN, mass_g, ventricular_function

VOXEL_COLUMNS = ("LVEDV voxel (mL)", "LVESV voxel (mL)", "LVEF voxel (%)",
                 "RVEDV voxel (mL)", "RVESV voxel (mL)", "RVEF voxel (%)", "LVM voxel (g)")


def voxel_metrics(voxel_volumes_ml: dict, ed_frame: int, es_frame: int) -> dict[str, float]:
    """The VOXEL_COLUMNS from per-frame voxel-count volumes (frame -> structure -> mL).

    Parameters
    ----------
    voxel_volumes_ml : dict
        Frame -> structure -> mL (``study.meta["voxel_volumes_ml"]``).
    ed_frame, es_frame : int
        The model's ED and ES frames.

    Returns
    -------
    dict of str to float
        Voxel column -> mL, g or % (NaN where the frame is not labelled).
    """
    def v(frame, key):
        x = voxel_volumes_ml.get(frame, voxel_volumes_ml.get(str(frame), {})).get(key)
        return float(x) if x is not None else NAN

    out = {c: NAN for c in VOXEL_COLUMNS}
    for side, cav in (("LV", "lv_cavity"), ("RV", "rv_cavity")):
        edv, esv = v(ed_frame, cav), v(es_frame, cav)
        out[f"{side}EDV voxel (mL)"], out[f"{side}ESV voxel (mL)"] = edv, esv
        out[f"{side}EF voxel (%)"] = ventricular_function(edv, esv, NAN)["EF"]
    out["LVM voxel (g)"] = mass_g(v(ed_frame, "lv_myocardium"))
    return {k: (x if math.isfinite(x) else NAN) for k, x in out.items()}


# ------------------------------------------------------------------ QC against the labels
#: largest |model − voxel count| that partial volume explains, % of the voxel count (volumes,
#: LVM) or EF points: voxel counting's own error on phantoms (up to 3 % EDV, 12 % ESV, 10 %
#: LVM, 3 / 7 points LVEF / RVEF at 10 mm slices; reports/validation-labelmaps.md) plus the
#: model's (3 % volumes, 5 % LVM, 2 points EF)
VOXEL_BOUND = {"LVEDV (mL)": 6.0, "RVEDV (mL)": 6.0, "LVESV (mL)": 15.0, "RVESV (mL)": 15.0,
               "LVM (g)": 15.0, "LVEF (%)": 5.0, "RVEF (%)": 10.0}
#: largest difference between the model's and the labels' ED -> ES change of the LV
#: myocardial volume (share of ED)
MYO_CHANGE_BOUND = 0.10
#: largest departure of the ES frame's labelled LV myocardium from its neighbours' mean
ES_NEIGHBOUR_BOUND = 0.15
#: the metrics that use the ES frame (the flags on ES evidence go to them)
ES_METRICS = ("LVESV (mL)", "LVEF (%)", "LVSV (mL)")


def is_finite_number(x: object) -> TypeGuard[int | float]:
    """Whether ``x`` is an int or float and finite (not NaN, not ±inf).

    Parameters
    ----------
    x : object
        A value.

    Returns
    -------
    bool
    """
    return isinstance(x, (int, float)) and math.isfinite(x)


def voxel_disagreement(metrics: dict) -> dict[str, list[str]]:
    """Flags of the metrics whose model value and voxel count differ beyond
    :data:`VOXEL_BOUND` (metric -> flags).

    Parameters
    ----------
    metrics : dict
        The metrics with their voxel columns.

    Returns
    -------
    dict of str to list of str
    """
    out: dict[str, list[str]] = {}
    for col, bound in VOXEL_BOUND.items():
        m, v = metrics.get(col), metrics.get(col.replace(" (", " voxel ("))
        if not (is_finite_number(m) and is_finite_number(v)) or (not col.endswith("(%)") and v <= 0):
            continue
        pct = col.endswith("(%)")
        d = m - v if pct else 100.0 * (m / v - 1.0)
        if abs(d) > bound:
            unit = " points" if pct else " %"
            out[col] = [f"{col.split(' (')[0]} model {m:.1f} vs voxel count {v:.1f} "
                        f"({d:+.1f}{unit}, beyond {bound:g}{unit})"]
    return out


def myocardium_flags(voxel_volumes_ml: dict, ed: int, es: int,
                     model_myo: tuple[float, float] | None = None) -> list[str]:
    """Flags on the ES evidence of a label-map study.

    Parameters
    ----------
    voxel_volumes_ml : dict
        Frame -> structure -> mL of the label map (``lv_myocardium`` used).
    ed, es : int
        The model's ED and ES frames.
    model_myo : (float, float) or None
        The model's LV myocardial volume (mL) at ED and ES.

    Returns
    -------
    list of str
        "LV myocardium ED->ES model ... vs labels ..." when the model's change departs from
        the labels' by more than :data:`MYO_CHANGE_BOUND`; "ES frame's labelled LV
        myocardium ... off its neighbours'" when frames es - 1 and es + 1 are labelled and
        the ES count departs from their mean by more than :data:`ES_NEIGHBOUR_BOUND`.
    """
    def myo(f):
        d = voxel_volumes_ml.get(f, voxel_volumes_ml.get(str(f))) or {}
        x = d.get("lv_myocardium")
        return float(x) if is_finite_number(x) and x > 0 else None

    out = []
    a, b = myo(ed), myo(es)
    if a and b and model_myo is not None and all(is_finite_number(x) and x > 0 for x in model_myo):
        lab, mod = b / a - 1.0, model_myo[1] / model_myo[0] - 1.0
        if abs(mod - lab) > MYO_CHANGE_BOUND:
            out.append(f"LV myocardium ED->ES: model {100 * mod:+.0f} % vs labels "
                       f"{100 * lab:+.0f} % (beyond {100 * MYO_CHANGE_BOUND:.0f} points)")
    nb = [myo(es - 1), myo(es + 1)]
    if b and all(nb):
        ref = 0.5 * (nb[0] + nb[1])
        if abs(b / ref - 1.0) > ES_NEIGHBOUR_BOUND:
            out.append(f"ES frame {es}: labelled LV myocardium {b:.0f} mL is {100 * (b / ref - 1):+.0f} % "
                       f"off its neighbours' {ref:.0f} mL (beyond {100 * ES_NEIGHBOUR_BOUND:.0f} %)")
    return out


def label_map_flags(model, metrics: dict) -> dict[str, list[str]]:
    """Every label-map QC flag of ``model`` (metric -> flags); {} for other studies.

    Parameters
    ----------
    model : BiventricularModel
        The model.
    metrics : dict
        Its metrics.

    Returns
    -------
    dict of str to list of str
    """
    vox = model.study.meta.get("voxel_volumes_ml") if isinstance(model.study.meta, dict) else None
    if not vox:
        return {}
    out = voxel_disagreement(metrics)
    ed, es = model.ed_frame, model.es_frame
    model_myo = None
    if ed != es:
        try:
            model_myo = (float(model.volumes[ed]["lv_myocardium"]),
                         float(model.volumes[es]["lv_myocardium"]))
        except (KeyError, TypeError):
            model_myo = None
    for flag in myocardium_flags(vox, ed, es, model_myo):
        for col in ES_METRICS:
            out.setdefault(col, []).append(flag)
    return out
