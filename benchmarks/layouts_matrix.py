"""Real files in other datasets' layouts read back the same (issues 29 and 30: "on real data we
keep aside").

    python benchmarks/layouts_matrix.py [--only A,B] [--labels-only | --cap-only]
        [--phantoms DIR [--phantoms-only]] [PATIENT]                    # default patient015

Each row builds, in a temporary folder, one layout as a dataset distributes it from the real
files in ../shared/data (an ACDC patient; bivme-patient1), loads it as ``cardionurbs analyze``
does (``load_study`` then ``analyse_study``) and compares every metric with the same data in
its original layout (ACDC patient folder / the CAP export as shipped). Label-map rows also
give the voxel count of the layout (it must equal the original's: same voxels). Status:
``ok`` (every metric within 2 % / 2 points of the original), ``DIFF`` (a metric beyond), or the
error line (``refused: ...``; expected for rows marked so). Printed as a markdown table.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import nibabel as nib
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cardionurbs.errors import StudyError  # noqa: E402
from cardionurbs.io import load_study  # noqa: E402
from cardionurbs.pipeline import analyse_study  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
KEYS = ("LVEDV (mL)", "LVESV (mL)", "RVEDV (mL)", "RVESV (mL)", "LVM (g)", "LVEF (%)", "RVEF (%)")
#: ACDC (1 RV, 2 MYO, 3 LV) -> UK Biobank / M&Ms (1 LV, 2 MYO, 3 RV)
TO_UKBB = np.array([0, 3, 2, 1], np.uint8)


# ------------------------------------------------------------------ ACDC pieces
def acdc_info(src: Path) -> dict[str, str]:
    out = {}
    for line in (src / "Info.cfg").read_text().splitlines():
        k, v = line.split(":", 1)
        out[k.strip()] = v.strip()
    return out


def acdc_frames(src: Path) -> tuple[int, int, int]:
    info = acdc_info(src)
    return int(info["ED"]), int(info["ES"]), int(info["NbFrame"])


def gt(src: Path, frame: int) -> nib.Nifti1Image:
    return nib.load(str(next(src.glob(f"*_frame{frame:02d}_gt.nii*"))))


def real_affine(zooms) -> np.ndarray:
    """An oblique scanner affine (RAS, mm) with the given voxel sizes, as a scanner writes."""
    a, b = math.radians(35), math.radians(-20)
    rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    aff = np.eye(4)
    aff[:3, :3] = rz @ rx @ np.diag(zooms[:3])
    aff[:3, 3] = (-110.0, 95.0, -40.0)
    return aff


def save(data: np.ndarray, path: Path, aff: np.ndarray | None, like: nib.Nifti1Image | None = None,
         *, sform: int = 1, qform: int = 1, zooms=None, dt=None, tunit: str = "unknown",
         dtype=np.uint8) -> Path:
    """Write ``data`` with a header built the way the row says."""
    if like is not None and aff is None:
        img = nib.Nifti1Image(data.astype(dtype), like.affine, like.header.copy())
        img.set_data_dtype(dtype)
    else:
        img = nib.Nifti1Image(data.astype(dtype), aff)
        img.set_data_dtype(dtype)
        img.set_sform(aff, code=sform)
        img.set_qform(aff, code=qform)
    if zooms is not None:
        z = list(zooms) + ([dt] if data.ndim == 4 else [])
        img.header.set_zooms(z[: data.ndim])
    elif data.ndim == 4:
        img.header.set_zooms(list(img.header.get_zooms()[:3]) + [dt or 1.0])
    img.header.set_xyzt_units("mm", tunit)
    path.parent.mkdir(parents=True, exist_ok=True)
    nib.save(img, str(path))
    return path


def four_d(src: Path, lut=None, *, compact: bool = False) -> tuple[np.ndarray, int, int]:
    """The patient's ED and ES maps in a (x, y, z, NbFrame) volume (other frames 0), or
    (x, y, z, 2) when compact; returns (data, ED index, ES index), 0-based."""
    ed, es, nb = acdc_frames(src)
    a_ed = np.asanyarray(gt(src, ed).dataobj).astype(np.uint8)
    a_es = np.asanyarray(gt(src, es).dataobj).astype(np.uint8)
    if lut is not None:
        a_ed, a_es = lut[a_ed], lut[a_es]
    if compact:
        return np.stack([a_ed, a_es], axis=3), 0, 1
    out = np.zeros(a_ed.shape + (nb,), np.uint8)
    out[..., ed - 1], out[..., es - 1] = a_ed, a_es
    return out, ed - 1, es - 1


# ------------------------------------------------------------------ ACDC rows
def acdc_copy(src: Path, dest: Path, *, info: str | None = None, ext: str = ".nii.gz",
              header=None, keep_images: bool = True, four_d_image: bool = False) -> Path:
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "Info.cfg").write_bytes(info.encode() if info is not None
                                    else (src / "Info.cfg").read_bytes())
    for f in sorted(src.glob("*.nii.gz")):
        if "_gt" not in f.name and not keep_images:
            continue
        name = f.name.replace(".nii.gz", ext)
        if header is None or "_gt" not in f.name:
            img = nib.load(str(f))
            nib.save(img, str(dest / name))
        else:
            header(nib.load(str(f)), dest / name)
    if four_d_image:
        ed, es, nb = acdc_frames(src)
        im = nib.load(str(next(f for f in src.glob("*_frame*.nii.gz") if "_gt" not in f.name)))
        a = np.asanyarray(im.dataobj)
        img = nib.Nifti1Image(np.repeat(a[..., None], nb, axis=3), im.affine, im.header.copy())
        nib.save(img, str(dest / f"{src.name}_4d.nii.gz"))
    return dest


def header_variant(kind: str):
    """A function writing one ACDC label map with the header variant ``kind``."""
    def write(img: nib.Nifti1Image, path: Path) -> None:
        a = np.asanyarray(img.dataobj).astype(np.uint8)
        z = img.header.get_zooms()[:3]
        aff = real_affine(z)
        if kind == "qform-only":
            save(a, path, aff, sform=0, qform=1)
        elif kind == "sform-only":
            save(a, path, aff, sform=1, qform=0)
        elif kind == "sform+qform disagree":
            img2 = nib.Nifti1Image(a, aff)
            img2.set_sform(aff, code=1)
            q = aff.copy()
            q[:3, 3] += 7.0
            img2.set_qform(q, code=1)
            nib.save(img2, str(path))
        elif kind == "LPS (x, y reversed)":
            flip = np.eye(4)
            flip[0, 0] = flip[1, 1] = -1
            flip[0, 3], flip[1, 3] = a.shape[0] - 1, a.shape[1] - 1
            save(a[::-1, ::-1], path, aff @ flip)
        elif kind == "slices reversed (real affine)":
            flip = np.eye(4)
            flip[2, 2], flip[2, 3] = -1, a.shape[2] - 1
            save(a[:, :, ::-1], path, aff @ flip)
        elif kind in ("int16", "float32", "float64", "int32"):
            save(a, path, None, img, dtype=np.dtype(kind))
        elif kind == "float32 scl_slope 1.0":
            im = nib.Nifti1Image(a.astype(np.float32), img.affine, img.header.copy())
            im.header.set_slope_inter(1.0, 0.0)
            nib.save(im, str(path))
        elif kind == "singleton 4th dim":
            save(a[..., None], path, None, img)
        elif kind == "singleton 4th+5th dims":
            save(a[..., None, None], path, None, img)
        elif kind == "stray label 4":
            b = a.copy()
            b[0, 0, 0] = 4
            save(b, path, None, img)
        elif kind == "int16 label 0/1/2/3 stored with scl 0":
            save(a, path, None, img, dtype=np.int16)
        else:
            raise KeyError(kind)
    return write


INFO_VARIANTS = {
    "Info.cfg reordered": lambda i: "".join(f"{k}: {i[k]}\n" for k in
                                            ("NbFrame", "Weight", "Height", "Group", "ES", "ED")),
    "Info.cfg CRLF": lambda i: "".join(f"{k}: {v}\r\n" for k, v in i.items()),
    "Info.cfg tabs and spaces": lambda i: "".join(f"{k}\t:\t {v}  \n" for k, v in i.items()),
    "Info.cfg 'ED : 01'": lambda i: "".join(f"{k} : {v.zfill(2) if k in ('ED', 'ES') else v}\n"
                                            for k, v in i.items()),
    "Info.cfg UTF-8 BOM": lambda i: "\ufeff" + "".join(f"{k}: {v}\n" for k, v in i.items()),
    "Info.cfg no Group (testing set)": lambda i: "".join(f"{k}: {v}\n" for k, v in i.items()
                                                         if k != "Group"),
    "Info.cfg 'ED: 1.0'": lambda i: "".join(f"{k}: {v + '.0' if k in ('ED', 'ES') else v}\n"
                                            for k, v in i.items()),
}


# ------------------------------------------------------------------ other datasets
def ukbb_4d(src: Path, dest: Path, *, dt: float, tunit: str, extra=(), compact=False) -> Path:
    data, ed, es = four_d(src, TO_UKBB, compact=compact)
    if ed != 0:
        raise ValueError("ukbb_cardiac's ED is frame 0")
    z = gt(src, 1).header.get_zooms()[:3]
    save(data, dest / "seg_sa.nii.gz", real_affine(z), zooms=z, dt=dt, tunit=tunit)
    if "ED/ES too" in extra:
        save(data[..., ed], dest / "seg_sa_ED.nii.gz", real_affine(z), zooms=z)
        save(data[..., es], dest / "seg_sa_ES.nii.gz", real_affine(z), zooms=z)
    if "sa image" in extra:
        save(data.astype(np.int16) * 100, dest / "sa.nii.gz", real_affine(z), zooms=z, dt=dt,
             tunit=tunit, dtype=np.int16)
    if "atrial seg_la_2ch" in extra:
        la = np.zeros((64, 64, 1, data.shape[3]), np.uint8)
        la[20:40, 20:40] = 1
        save(la, dest / "seg_la_2ch.nii.gz", real_affine((1.8, 1.8, 6.0)), zooms=(1.8, 1.8, 6.0),
             dt=dt, tunit=tunit)
    if "atrial seg_la_4ch" in extra:
        la = np.zeros((64, 64, 1, data.shape[3]), np.uint8)
        la[10:30, 20:40] = 1
        la[32:50, 20:40] = 2
        save(la, dest / "seg_la_4ch.nii.gz", real_affine((1.8, 1.8, 6.0)), zooms=(1.8, 1.8, 6.0),
             dt=dt, tunit=tunit)
    return dest


def ukbb_ed_es(src: Path, dest: Path) -> Path:
    data, ed, es = four_d(src, TO_UKBB)
    z = gt(src, 1).header.get_zooms()[:3]
    save(data[..., ed], dest / "seg_sa_ED.nii.gz", real_affine(z), zooms=z)
    save(data[..., es], dest / "seg_sa_ES.nii.gz", real_affine(z), zooms=z)
    return dest


def mnms1(src: Path, root: Path, *, csv_where: str, ed_es=True) -> Path:
    """M&Ms-1 OpenDataset/Training/Labeled/<code>/<code>_sa(_gt).nii.gz + the dataset CSV."""
    code = "A1B2C3"
    data, ed, es = four_d(src, TO_UKBB)
    z = gt(src, 1).header.get_zooms()[:3]
    subj = root / "OpenDataset" / "Training" / "Labeled" / code
    save(data, subj / f"{code}_sa_gt.nii.gz", real_affine(z), zooms=z, dt=30.0, tunit="msec")
    save(data.astype(np.int16) * 100, subj / f"{code}_sa.nii.gz", real_affine(z), zooms=z, dt=30.0,
         tunit="msec", dtype=np.int16)
    table = (",External code,VendorName,Vendor,Centre,ED,ES,Age,Pathology,Sex,Height,Weight\n"
             f"0,ZZZZZZ,Siemens,A,1,0,9,50,NOR,M,170,70\n"
             f"1,{code},Philips,B,2,{ed},{es},61,HCM,F,165,60\n")
    where = {"root": root / "OpenDataset", "subject": subj, "parent": subj.parent, "none": None}[csv_where]
    if where is not None and ed_es:
        (where / "211230_M&Ms_Dataset_information_diagnosis_opendataset.csv").write_text(table)
    return subj


def mnms2(src: Path, root: Path, *, cine=True, ext=".nii.gz") -> Path:
    code = "001"
    data, ed, es = four_d(src, TO_UKBB)
    z = gt(src, 1).header.get_zooms()[:3]
    subj = root / "dataset" / code
    for ph, t in (("ED", ed), ("ES", es)):
        save(data[..., t], subj / f"{code}_SA_{ph}_gt{ext}", real_affine(z), zooms=z)
        save(data[..., t].astype(np.int16) * 100, subj / f"{code}_SA_{ph}{ext}", real_affine(z),
             zooms=z, dtype=np.int16)
    if cine:
        save(data.astype(np.int16) * 100, subj / f"{code}_SA_CINE{ext}", real_affine(z), zooms=z,
             dt=30.0, tunit="msec", dtype=np.int16)
    (root / "dataset_information.csv").write_text("SUBJECT_CODE,DISEASE,VENDOR,SCANNER,FIELD\n"
                                                  f"{code},NOR,SIEMENS,Avanto,1.5\n")
    return subj


# ------------------------------------------------------------------ rows
def label_rows(src: Path, tmp: Path) -> list[tuple[str, Path, dict, str]]:
    """(layout, path, load_study kwargs, expectation) for one ACDC patient."""
    p = src.name
    info = acdc_info(src)
    rows = [("ACDC as distributed", src, {}, "ref")]
    rows.append(("ACDC training/ tree + patientNNN_4d image", acdc_copy(
        src, tmp / "database" / "training" / p, four_d_image=True), {}, "same"))
    rows.append(("ACDC .nii (uncompressed)", acdc_copy(src, tmp / "nii" / p, ext=".nii"), {}, "same"))
    rows.append(("ACDC labels only (no frame images)", acdc_copy(src, tmp / "gtonly" / p,
                                                                 keep_images=False), {}, "same"))
    for name, fn in INFO_VARIANTS.items():
        rows.append((name, acdc_copy(src, tmp / name.replace(" ", "_").replace("'", "")
                                     .replace(":", "") / p, info=fn(info), keep_images=False),
                     {}, "same"))
    for kind in ("qform-only", "sform-only", "sform+qform disagree", "LPS (x, y reversed)",
                 "slices reversed (real affine)", "int16", "int32", "float32", "float64",
                 "float32 scl_slope 1.0", "singleton 4th dim", "singleton 4th+5th dims",
                 "stray label 4"):
        d = acdc_copy(src, tmp / ("h_" + "".join(c if c.isalnum() else "_" for c in kind)) / p,
                      header=header_variant(kind), keep_images=False)
        rows.append((f"header: {kind}", d, {}, "refused" if kind == "stray label 4" else "same"))
    ed, es, _ = acdc_frames(src)
    rows.append(("ACDC single frame map (ED alone)", next(src.glob(f"*_frame{ed:02d}_gt.nii.gz")),
                 {}, "EF null"))
    # UK Biobank
    z = tmp / "ukbb"
    rows.append(("ukbb seg_sa 4-D, dt 0.03 unknown unit (s)", ukbb_4d(src, z / "a", dt=0.03, tunit="unknown"),
                 {}, "same"))
    rows.append(("ukbb seg_sa 4-D, dt 30 msec + sa + seg_sa_ED/ES",
                 ukbb_4d(src, z / "b", dt=30.0, tunit="msec", extra=("ED/ES too", "sa image")), {}, "same"))
    rows.append(("ukbb seg_sa 4-D, dt in sec declared", ukbb_4d(src, z / "c", dt=0.03, tunit="sec"),
                 {}, "same"))
    rows.append(("ukbb seg_sa_ED + seg_sa_ES", ukbb_ed_es(src, z / "d"), {}, "same"))
    rows.append(("ukbb seg_sa + atrial seg_la_2ch (label 1 LA)",
                 ukbb_4d(src, z / "e", dt=0.03, tunit="unknown", extra=("atrial seg_la_2ch",)), {}, "same"))
    rows.append(("ukbb seg_sa + atrial seg_la_4ch (1 LA, 2 RA)",
                 ukbb_4d(src, z / "f", dt=0.03, tunit="unknown", extra=("atrial seg_la_4ch",)), {}, "same"))
    rows.append(("ukbb seg_sa.nii.gz alone, as one file", ukbb_4d(src, z / "g", dt=0.03, tunit="unknown")
                 / "seg_sa.nii.gz", {"labels": "ukbb"}, "same"))
    # M&Ms-1
    for where in ("root", "parent", "subject", "none"):
        rows.append((f"M&Ms-1 OpenDataset tree, CSV in {where}", mnms1(src, tmp / f"mnms_{where}", csv_where=where),
                     {}, "same"))
    rows.append(("M&Ms-1 OpenDataset tree, CSV in root, --allow-outside", tmp / "mnms_root" / "OpenDataset"
                 / "Training" / "Labeled" / "A1B2C3", {"allow_outside": True}, "same"))
    d = ukbb_ed_es(src, z / "h")
    data, ed0, es0 = four_d(src, TO_UKBB)
    zz = gt(src, 1).header.get_zooms()[:3]
    for ph, t in (("ED", ed0), ("ES", es0)):       # an LA plane through the stack (a mid row)
        la_aff = real_affine(zz) @ np.array([[1, 0, 0, 0], [0, 0, 1, data.shape[1] // 2],
                                             [0, 1, 0, 0], [0, 0, 0, 1.0]])
        save(data[:, data.shape[1] // 2, :, t][:, :, None], d / f"seg4_la_4ch_{ph}.nii.gz", la_aff)
    rows.append(("ukbb seg_sa_ED/ES + seg4_la_4ch_ED/ES", d, {}, "informative"))
    s = mnms1(src, tmp / "mnms_file", csv_where="none")
    rows.append(("M&Ms-1 <code>_sa_gt.nii.gz as one file + --ed-frame/--es-frame",
                 next(s.glob("*_sa_gt.nii.gz")), {"ed_frame": ed - 1, "es_frame": es - 1, "labels": "mnms"}, "same"))
    # M&Ms-2
    rows.append(("M&Ms-2 dataset/NNN with SA_CINE", mnms2(src, tmp / "mnms2a"), {}, "same"))
    rows.append(("M&Ms-2 .nii", mnms2(src, tmp / "mnms2b", ext=".nii", cine=False), {}, "same"))
    return rows


# ------------------------------------------------------------------ CAP / biv-me exports
BIVME = DATA / "bivme-patient1"
COLS = ["x", "y", "z", "contour type", "frameID", "weight", "time frame"]


def gp_rows(path: Path) -> tuple[str, list[list[str]]]:
    lines = path.read_text().splitlines()
    return lines[0], [ln.split("\t") for ln in lines[1:]]


def cap_copy(dest: Path, *, edit=None, name=None, sep="\t", eol="\n", header=None, order=None,
             drop_frames=(), slice_info=None) -> Path:
    """A copy of bivme-patient1 with each GPFile's rows passed through ``edit(frame, rows)``,
    renamed by ``name(frame)``, written with ``sep``/``eol``, the header ``header`` (None:
    as shipped, "" none), the columns in ``order``; frames in ``drop_frames`` left out."""
    dest.mkdir(parents=True)
    si = (BIVME / "SliceInfoFile.txt").read_text()
    (dest / "SliceInfoFile.txt").write_text(slice_info(si) if slice_info else si)
    for f in sorted(BIVME.glob("GPFile_*.txt")):
        frame = int(f.stem.split("_")[1])
        if frame in drop_frames:
            continue
        head, rows = gp_rows(f)
        if edit:
            rows = edit(frame, rows)
        cols = COLS
        if order:
            rows = [[r[COLS.index(c)] for c in order] for r in rows]
            cols = order
        head = "\t".join(cols) if order else (head if header is None else header)
        text = ([head] if head else []) + [sep.join(r) for r in rows]
        (dest / (name(frame) if name else f.name)).write_text(eol.join(text) + eol)
    return dest


def la_as_sax(frame, rows):
    """The points of the first long-axis slice's LV endocardium labelled SAX (issue 30 item 1)."""
    la = sorted({r[4] for r in rows if r[3] == "LAX_LV_ENDOCARDIAL"})[:1]
    return [[*r[:3], "SAX_LV_ENDOCARDIAL", *r[4:]] if r[3] == "LAX_LV_ENDOCARDIAL" and r[4] in la
            else r for r in rows]


def sa_as_lax(frame, rows):
    """The points of one mid short-axis slice's LV endocardium labelled LAX."""
    sa = sorted({r[4] for r in rows if r[3] == "SAX_LV_ENDOCARDIAL"}, key=int)
    mid = sa[len(sa) // 2] if sa else None
    return [[*r[:3], "LAX_LV_ENDOCARDIAL", *r[4:]] if r[3] == "SAX_LV_ENDOCARDIAL" and r[4] == mid
            else r for r in rows]


def frameid_style(dest: Path) -> Path:
    """bivme-patient1 written back with the CAP export's SliceInfoFile (frameID:, per frame)."""
    from cardionurbs.io import gpfile
    gpfile.write_study(load_study(BIVME), dest, style="frameID")
    return dest


def cap_rows(tmp: Path) -> list[tuple[str, Path, dict, str]]:
    z = tmp / "cap"
    return [
        ("CAP bivme-patient1 as shipped", BIVME, {}, "ref"),
        ("CAP spaces between fields", cap_copy(z / "a", sep=" "), {}, "same"),
        ("CAP CRLF line ends", cap_copy(z / "b", eol="\r\n"), {}, "same"),
        ("CAP no header line", cap_copy(z / "c", header=""), {}, "same"),
        ("CAP header 'sliceID' (biv-me v2 name)", cap_copy(
            z / "d", header="x\ty\tz\tcontour type\tsliceID\tweight\ttime frame"), {}, "same"),
        ("CAP columns reordered (named by the header)", cap_copy(
            z / "e", order=["contour type", "frameID", "x", "y", "z", "weight", "time frame"]), {}, "same"),
        ("CAP frames numbered from 1 (GPFile_001..)", cap_copy(
            z / "f", name=lambda f: f"GPFile_{f + 1:03d}.txt",
            edit=lambda f, rows: [[*r[:6], str(f + 1)] for r in rows]), {}, "same"),
        ("CAP frames as GPFile_N.txt (no zero padding)", cap_copy(
            z / "g", name=lambda f: f"GPFile_{f}.txt"), {}, "same"),
        ("CAP frame 12 missing", cap_copy(z / "h", drop_frames=(12,)), {}, "same"),
        ("CAP a long-axis slice labelled SAX", cap_copy(z / "i", edit=la_as_sax), {}, "same"),
        ("CAP no RV epicardium", cap_copy(
            z / "j", edit=lambda f, rows: [r for r in rows if "RV_EPICARDIAL" not in r[3]]), {}, "RVM null"),
        ("CAP a short-axis slice labelled LAX", cap_copy(z / "m", edit=sa_as_lax), {}, "same"),
        ("CAP lines ending in a tab (8th empty field)", cap_copy(
            z / "n", edit=lambda f, rows: [[*r, ""] for r in rows]), {}, "same"),
        ("CAP no landmarks (contours only)", cap_copy(
            z / "o", edit=lambda f, rows: [r for r in rows if r[3].startswith(("SAX_", "LAX_"))]),
         {}, "informative"),
        ("CAP SliceInfoFile frameID style (per frame, timeFrame)", frameid_style(z / "p"), {}, "same"),
        ("CAP SliceInfoFile with spaces", cap_copy(
            z / "k", slice_info=lambda t: t.replace("\t", " ")), {}, "same"),
        ("CAP SliceInfoFile CRLF", cap_copy(
            z / "l", slice_info=lambda t: t.replace("\n", "\r\n")), {}, "same"),
    ]


# ------------------------------------------------------------------ phantoms in real layouts
def _copy_maps(src: Path, dest: Path, rename=None, skip=()) -> Path:
    dest.mkdir(parents=True)
    for f in sorted(src.iterdir()):
        if f.name not in skip:
            shutil.copy(f, dest / (rename(f.name) if rename else f.name))
    return dest


def _atrial(path: Path, dest: Path, labels: dict[int, int]) -> None:
    """``path``'s map relabelled as ukbb_cardiac's atrial networks write it (old -> new
    value; the rest 0): seg_la_2ch = 1 LA, seg_la_4ch = 1 LA, 2 RA."""
    img = nib.load(str(path))
    a = np.asanyarray(img.dataobj)
    out = np.zeros_like(a)
    for old, new in labels.items():
        out[a == old] = new
    nib.save(nib.Nifti1Image(out, img.affine, img.header), str(dest))


def _frames_of(path: Path, dest_stem: Path, frames: dict[str, int]) -> None:
    img = nib.load(str(path))
    a = np.asanyarray(img.dataobj)
    for ph, t in frames.items():
        hdr = img.header.copy()
        nib.save(nib.Nifti1Image(a[..., t], img.affine, hdr), f"{dest_stem}_{ph}.nii.gz")


def phantom_rows(root: Path, tmp: Path) -> list[tuple[str, Path, dict, str]]:
    """Phantom label maps (``cardionurbs phantom --labels L --label-quirks real --out
    ROOT/ph_L``) rearranged as each dataset distributes them; compared with the truth."""
    rows: list[tuple[str, Path, dict, str]] = []
    z = tmp / "ph"
    u = root / "ph_ukbb" / "labelmaps"
    if u.is_dir():
        rows.append(("phantom ukbb as written (seg_sa + seg4_la_4ch + seg_la_2ch/3ch)", u, {}, "truth"))
        d = _copy_maps(u, z / "u1", skip=("seg_la_2ch.nii.gz",))
        _atrial(u / "seg_la_2ch.nii.gz", d / "seg_la_2ch.nii.gz", {4: 1})
        _atrial(u / "seg4_la_4ch.nii.gz", d / "seg_la_4ch.nii.gz", {4: 1, 5: 2})
        rows.append(("phantom ukbb + atrial seg_la_2ch, seg_la_4ch (ukbb_cardiac's atrial nets)",
                     d, {}, "truth"))
        es = json_truth(root / "ph_ukbb")["es_frame"]
        d = z / "u2"
        d.mkdir(parents=True)
        _frames_of(u / "seg_sa.nii.gz", d / "seg_sa", {"ED": 0, "ES": es})
        _frames_of(u / "seg4_la_4ch.nii.gz", d / "seg4_la_4ch", {"ED": 0, "ES": es})
        _frames_of(u / "seg_la_2ch.nii.gz", d / "seg_la_2ch", {"ED": 0, "ES": es})
        rows.append(("phantom ukbb seg_sa_ED/ES + seg4_la_4ch_ED/ES + seg_la_2ch_ED/ES", d, {}, "truth"))
    m = root / "ph_mnms" / "labelmaps"
    if m.is_dir():
        rows.append(("phantom M&Ms-1 as written (CSV beside)", m, {}, "truth"))
        code = next(m.glob("*_sa_gt.nii.gz")).name[:-len("_sa_gt.nii.gz")]
        subj = _copy_maps(m, z / "m1" / "OpenDataset" / "Training" / "Labeled" / code, skip=("mnms_info.csv",))
        table = (m / "mnms_info.csv").read_text().splitlines()
        ed_es = table[1].split(",")[1:3]
        (z / "m1" / "OpenDataset" / "211230_M&Ms_Dataset_information_diagnosis_opendataset.csv").write_text(
            ",External code,VendorName,Vendor,Centre,ED,ES,Age,Pathology,Sex,Height,Weight\n"
            f"0,{code},Siemens,A,1,{ed_es[0]},{ed_es[1]},50,NOR,M,170,70\n")
        rows.append(("phantom M&Ms-1 OpenDataset tree, table at the root, --allow-outside", subj,
                     {"allow_outside": True}, "truth"))
        rows.append(("phantom M&Ms-1 OpenDataset tree, table at the root", subj, {}, "truth"))
    m2 = root / "ph_mnms2" / "labelmaps"
    if m2.is_dir():
        rows.append(("phantom M&Ms-2 as written (SA + LA ED/ES)", m2, {}, "truth"))
        code = next(m2.glob("*_SA_ED_gt.nii.gz")).name[:-len("_SA_ED_gt.nii.gz")]
        d = _copy_maps(m2, z / "m2" / "dataset" / "001", rename=lambda n: n.replace(code, "001"))
        shutil.copy(root / "ph_ukbb" / "labelmaps" / "sa.nii.gz", d / "001_SA_CINE.nii.gz") \
            if (root / "ph_ukbb").is_dir() else None
        rows.append(("phantom M&Ms-2 dataset/001 + SA_CINE", d, {}, "truth"))
    a = root / "ph_acdc" / "labelmaps"
    if a.is_dir():
        rows.append(("phantom ACDC as written (real header, 4d image)", a, {}, "truth"))
        d = _copy_maps(a, z / "a" / "database" / "testing" / "patient101",
                       rename=lambda n: n.replace(next(a.glob("*_4d.nii.gz")).name[:-len("_4d.nii.gz")],
                                                  "patient101"))
        rows.append(("phantom ACDC testing/patient101 names", d, {}, "truth"))
    return rows


def json_truth(folder: Path) -> dict:
    import json
    return json.loads((folder / "truth.json").read_text())


def run(path: Path, kw: dict) -> tuple[str, dict | None, dict | None, float]:
    t0 = time.perf_counter()
    try:
        study = load_study(path, **kw)
        _, m = analyse_study(study)
    except StudyError as exc:
        return f"refused: {exc}", None, None, time.perf_counter() - t0
    except Exception as exc:  # noqa: BLE001 - a crash is a row of the matrix
        return f"CRASH {type(exc).__name__}: {exc}", None, None, time.perf_counter() - t0
    vox = study.meta.get("voxel_volumes_ml")
    la = sorted({c.slice for c in study.contours if c.view == "LA"})
    return "", m, {"vox": vox, "ed": study.ed_frame, "es": study.es_frame,
                   "src": study.meta.get("ed_es_source"), "n_warn": len(study.warnings),
                   "la": ",".join(la) if study.meta.get("format") == "nifti" else f"{len(la)} LA"}, \
        time.perf_counter() - t0


def compare(m: dict, ref: dict, vol_rel: float = 0.02, mass_rel: float = 0.02,
            pts: float = 2.0) -> list[str]:
    out = []
    for k in KEYS:
        a, b = m.get(k, float("nan")), ref.get(k, float("nan"))
        if not (np.isfinite(a) and np.isfinite(b)):
            if np.isfinite(a) != np.isfinite(b):
                out.append(f"{k.split(' ')[0]} {a} vs {b}")
            continue
        lim = pts if "%" in k else (mass_rel if "(g)" in k else vol_rel) * abs(b)
        if abs(a - b) > lim:
            out.append(f"{k.split(' ')[0]} {a:.1f} vs {b:.1f}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("patient", nargs="?", default="patient015")
    ap.add_argument("--only", default="", help="rows whose name holds one of these (comma-separated)")
    ap.add_argument("--cap-only", action="store_true")
    ap.add_argument("--labels-only", action="store_true")
    ap.add_argument("--phantoms", default="", help="folder of phantom outputs ph_{ukbb,mnms,mnms2,acdc}")
    ap.add_argument("--phantoms-only", action="store_true")
    args = ap.parse_args()
    src = DATA / "acdc" / args.patient
    print("| layout | expected | status | LVEDV | LVESV | RVEDV | LVM | LVEF | RVEF | ED/ES (rule) "
          "| LA used | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        ref = None
        rows = [] if args.cap_only else label_rows(src, Path(tmp))
        rows += cap_rows(Path(tmp)) if not (args.labels_only or args.phantoms_only) else []
        if args.phantoms_only:
            rows = []
        if args.phantoms:
            rows += phantom_rows(Path(args.phantoms), Path(tmp))
            truths = {r: json_truth(Path(args.phantoms) / r)["metrics"] for r in
                      ("ph_ukbb", "ph_mnms", "ph_mnms2", "ph_acdc")
                      if (Path(args.phantoms) / r / "truth.json").is_file()}
        for name, path, kw, expect in rows:
            if args.only and not any(o in name for o in args.only.split(",")) and expect != "ref":
                continue
            err, m, info, dt = run(path, kw)
            if expect == "ref":
                ref = m
            if err:
                status = err if expect == "refused" else f"**{err}**"
                print(f"| {name} | {expect} | {status[:220]} |" + " |" * 8 + f" {dt:.0f} |", flush=True)
                continue
            if expect == "truth":
                key = {"ukbb": "ph_ukbb", "m&ms-1": "ph_mnms", "m&ms-2": "ph_mnms2",
                       "acdc": "ph_acdc"}[name.split(" ")[1].lower()]
                bad = compare(m, truths[key], vol_rel=0.03, mass_rel=0.05, pts=2.0)
            else:
                bad = compare(m, ref) if expect not in ("EF null", "RVM null", "informative") else []
            if expect == "RVM null" and np.isfinite(m.get("RVM (g)", np.nan)):
                bad = ["RVM given without an RV epicardium"]
            status = "ok" if not bad else "**DIFF** " + "; ".join(bad)
            cells = [f"{m[k]:.1f}" for k in ("LVEDV (mL)", "LVESV (mL)", "RVEDV (mL)", "LVM (g)",
                                             "LVEF (%)", "RVEF (%)")]
            rule = (info["src"] or "model: LV volumes").split(" (")[0].split(":")[0]
            print(f"| {name} | {expect} | {status} | " + " | ".join(cells)
                  + f" | {info['ed']}/{info['es']} ({rule}) | {info['la'] or '-'} | {dt:.0f} |", flush=True)
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
