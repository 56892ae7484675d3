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

from cardionurbs.analysis.function import NAN, mass_g, ventricular_function

VOXEL_COLUMNS = ("LVEDV voxel (mL)", "LVESV voxel (mL)", "LVEF voxel (%)",
                 "RVEDV voxel (mL)", "RVESV voxel (mL)", "RVEF voxel (%)", "LVM voxel (g)")


def voxel_metrics(voxel_volumes_ml: dict, ed_frame: int, es_frame: int) -> dict[str, float]:
    """The VOXEL_COLUMNS from per-frame voxel-count volumes (frame -> structure -> mL)."""
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
