"""Where an SA-only label-map volume error comes from: basal cap, sectioned middle, apical cap.

    python benchmarks/labelmap_caps.py normal:0:208 phtn:0:208 [mr:1:168:ukbb ...]
    python benchmarks/labelmap_caps.py --slabs ../shared/data/acdc/patient075 [...]

``--slabs STUDY``: a label-map study (an ACDC patient as distributed, a phantom's labelmaps
folder) read and reconstructed; at ED and ES, per labelled slice (base first), the label
area times the slice spacing (the slab voxel counting gives the slice) beside the model's
volume between the planes half-way to the neighbouring slices (the end slabs reach half a
spacing beyond the end slices), for the LV cavity, LV myocardium and RV cavity, and what
the model holds beyond the end slabs. Shows where a model/voxel-count difference sits.

Each argument is pathology:seed:matrix[:layout] (layout acdc by default). The phantom is
written as label maps, read back and reconstructed; at ED and ES each cavity (and the LV
myocardium) is cut by the planes of its most basal and most apical sections, and the three
parts are compared with the analytic truth, counted on a 0.5 mm grid of the phantom's tissue
codes (:func:`cardionurbs.phantom.labelmaps.tissue_codes`). Also printed: how far the truth
and the model extend beyond the outermost sections (base and tip, mm). Prints a table.
"""
import sys, tempfile
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from cardionurbs.io import load_study
from cardionurbs.phantom.generate import generate
from cardionurbs.phantom.labelmaps import write_labelmaps, tissue_codes, LV, MYO_LV, RV
from cardionurbs.anatomy.model import reconstruct
from cardionurbs.analysis.function import measure

def truth_profile(ph, f_idx, n, step=0.5):
    an, pose = ph.anatomy, ph.pose
    f = float(ph.phases[f_idx])
    R = max(an.r_short_epi, an.r_free_endo * (1 + an.rv_offset) + an.rv_wall) + 10
    xs = np.arange(-R, R, step) + step / 2
    zs = np.arange(-15, an.z_base + 30, step) + step / 2
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    X, Y = X.ravel(), Y.ravel()
    out = {LV: [], MYO_LV: [], RV: []}
    for z in zs:
        hp = np.column_stack([X, Y, np.full(X.size, z)])
        c = tissue_codes(ph, hp, f)
        sc = hp @ pose.rotation.T + pose.origin
        d = sc @ n
        for k in out:
            out[k].append(d[c == k])
    return {k: np.concatenate(v) for k, v in out.items()}, step ** 3 / 1000.0

def beyond(depths, dv, d0):
    return float((depths > d0).sum() * dv)

def model_beyond(solid, n, d0):
    m = solid.trim_by_plane(n, float(d0))
    return m.volume() / 1000.0

def run(path, seed, matrix, layout="acdc"):
    ph = generate(path, seed=seed, frames=20, matrix=matrix, fov_mm=300.0, volume_check=False)
    tmp = Path(tempfile.mkdtemp())
    write_labelmaps(ph, tmp, layout, frames=[0, ph.es_frame], images=False)
    st = load_study(tmp)
    if layout == "ukbb":
        st.ed_frame, st.es_frame = 0, 1
    model = reconstruct(st)
    m = measure(model)
    t = ph.truth["metrics"]
    res = []
    for lab, fr, fi in (("ED", model.ed_frame, 0), ("ES", model.es_frame, ph.es_frame)):
        geo = model.geometry[fr]
        n = geo.direction
        sol = model.solids(fr)
        prof, dv = truth_profile(ph, fi, n)
        for key, code in (("lv_cavity", LV), ("rv_cavity", RV), ("lv_myocardium", MYO_LV)):
            secs = geo.sections["lv_endo" if key != "rv_cavity" else "rv_endo"]
            if key == "lv_myocardium":
                secs = geo.sections["lv_epi"]
            d = [float(s.points.mean(axis=0) @ n) for s in secs]
            d0, d1 = min(d), max(d)
            tot_t = prof[code].size * dv
            tot_m = sol[key].volume() / 1000
            tb = tot_t - beyond(prof[code], dv, d0); mb = tot_m - model_beyond(sol[key], n, d0)
            ta = beyond(prof[code], dv, d1); ma = model_beyond(sol[key], n, d1)
            tm, mm = tot_t - tb - ta, tot_m - mb - ma
            ap = geo.apex.get("lv_endo" if key == "lv_cavity" else ("rv_endo" if key=="rv_cavity" else "lv_epi"))
            # true apex depth extent
            tip_t = prof[code].max() - d1
            tip_m = float(ap @ n) - d1
            base_t = d0 - prof[code].min()
            bp = geo.base_planes["lv" if key != "rv_cavity" else "rv"]
            base_m = d0 - float(bp.origin @ n)
            res.append((lab, key, tot_t, 100*(tot_m/tot_t-1), tb, mb, tm, mm, ta, ma, base_t, base_m, tip_t, tip_m, len(d)))
    print(f"== {path} seed {seed} {matrix} {layout}")
    print("ph  struct        truth   err%  | base t/m      | mid t/m         | apex t/m    | base ext t/m | tip ext t/m | nsl")
    for r in res:
        print(f"{r[0]} {r[1]:14s} {r[2]:7.1f} {r[3]:+6.2f} | {r[4]:5.1f} {r[5]:5.1f} | {r[6]:7.1f} {r[7]:7.1f} | {r[8]:5.2f} {r[9]:5.2f} | {r[10]:5.1f} {r[11]:5.1f} | {r[12]:5.1f} {r[13]:5.1f} | {r[14]}")

def slab_rows(model, frame, vox_areas, spacing):
    """Per slice (base first): (slice, {key: (label mL, model mL)}), and the model's mL
    beyond the end slabs ({key: (basal, apical)})."""
    geo = model.geometry[frame]
    n = geo.direction
    sol = model.solids(frame)
    ims = sorted({im.slice: im for im in model.study.images if im.view == "SA"}.values(),
                 key=lambda im: float(im.position @ n))
    lev = np.array([float(im.position @ n) for im in ims])
    edges = np.r_[lev[0] - spacing / 2, (lev[1:] + lev[:-1]) / 2, lev[-1] + spacing / 2]
    rows, ends = [], {}
    for key, m in sol.items():
        if key not in ("lv_cavity", "lv_myocardium", "rv_cavity"):
            continue
        above = [m.trim_by_plane(list(n), float(e)).volume() / 1000 for e in edges]  # apical of e
        tot = m.volume() / 1000
        ends[key] = (tot - above[0], above[-1])
        for i, im in enumerate(ims):
            if len(rows) <= i:
                rows.append((im.slice, {}))
            rows[i][1][key] = (vox_areas.get(im.slice, {}).get(key, 0.0) * spacing / 1000,
                               above[i] - above[i + 1])
    return rows, ends


def slabs(folder):
    """Print the per-slice table of ``--slabs`` (see the module docstring)."""
    st = load_study(folder)
    model = reconstruct(st)
    print(f"== {folder}  orientation: {st.meta.get('sa_orientation')}")
    for lab, fr in (("ED", model.ed_frame), ("ES", model.es_frame)):
        areas = label_areas(st, fr)
        sp = model.geometry[fr].thickness
        rows, ends = slab_rows(model, fr, areas, sp)
        print(f"{lab} frame {fr}, spacing {sp:.1f} mm, ES base shift "
              f"{model.base_shift_mm.get(fr, 0.0):+.2f} mm    label mL / model mL")
        print(f"{'slice':8s}" + "".join(f"{k:>20s}" for k in ("lv_cavity", "lv_myocardium", "rv_cavity")))
        for sl, d in rows:
            print(f"{sl:8s}" + "".join(f"{d[k][0]:9.1f} /{d[k][1]:7.1f}  " if k in d else f"{'':20s}"
                                       for k in ("lv_cavity", "lv_myocardium", "rv_cavity")))
        tot = {k: (sum(d[k][0] for _, d in rows if k in d), sum(d[k][1] for _, d in rows if k in d))
               for k in ends}
        print(f"{'beyond':8s}" + "".join(f"{ends[k][0]:8.1f}b {ends[k][1]:6.1f}a   " for k in ends))
        print(f"{'total':8s}" + "".join(f"{tot[k][0]:9.1f} /{tot[k][1] + sum(ends[k]):7.1f}  " for k in ends))


def label_areas(study, frame):
    """mm² per SA slice and structure of the ACDC-layout label map of ``frame`` (the file
    ``*_frameMM_gt``, MM = frame + 1), matched to the study's slices by position."""
    from cardionurbs.io.nifti import read_label_volume
    from cardionurbs.io.labels import PRESETS
    f = next(Path(study.source).glob(f"*_frame{frame + 1:02d}_gt.nii*"))
    vol = read_label_volume(f)
    a, r = vol.affine, PRESETS["acdc"]
    px = float(np.linalg.norm(a[:3, 0]) * np.linalg.norm(a[:3, 1]))
    centres = np.array([a[:3, 3] + k * a[:3, 2] for k in range(vol.data.shape[2])])
    out = {}
    for im in study.images:
        if im.view == "SA" and im.frame == frame:
            k = int(np.argmin(np.linalg.norm(centres - im.position, axis=1)))
            d = vol.data[:, :, k, 0]
            out[im.slice] = {"lv_cavity": (d == r.lv).sum() * px,
                             "lv_myocardium": (d == r.myo).sum() * px,
                             "rv_cavity": (d == r.rv).sum() * px}
    return out


if __name__ == "__main__":
    if sys.argv[1:2] == ["--slabs"]:
        for a in sys.argv[2:]:
            slabs(a)
        sys.exit(0)
    for a in sys.argv[1:]:
        p, s, mtx, *lay = a.split(":")
        run(p, int(s), int(mtx), *(lay or ["acdc"]))
