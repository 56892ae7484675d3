"""Where bivme-patient1's model differs from its contours (issue 13): per SA slice, per
level along the long axis, per LA view; figures into
reports/figures/validation/bivme-patient1/. Called by ``bench_models.py bivme``.

Every area is measured the same way for both sides: ours by cutting the model's solids
(manifold3d) with the image plane; the contours' as the polygons they enclose (the LV
wall: the LV epicardial loop, closed through the RV septum as the reconstruction closes
it, less the endocardial loop; the RV cavity: the RV loop outside the LV epicardial loop).
"""

from __future__ import annotations

from contextlib import ExitStack, contextmanager
from pathlib import Path
from unittest import mock

import numpy as np

from cardionurbs.anatomy import sections as sections_module
from cardionurbs.anatomy.model import reconstruct
from cardionurbs.anatomy.sections import join_open_parts
from cardionurbs.geometry import in_plane_basis, points_in_polygon, polygon_area

FIG = "figures/validation/bivme-patient1"
SA_FIGURE = f"{FIG}/sa_sections_ed.png"
PROFILE_FIGURE = f"{FIG}/area_profiles.png"
LA_FIGURE = f"{FIG}/la_views_frame9.png"
COLOURS = {"lv_cavity": "tab:red", "lv_myocardium": "tab:blue", "rv_cavity": "tab:green",
           "rv_myocardium": "tab:purple"}
POINT_COLOURS = {"lv_endo": "darkred", "lv_epi": "navy", "rv_freewall": "darkgreen",
                 "rv_septum": "lime", "rv_endo": "darkgreen", "rv_epi": "purple"}


def _frame_to_plane(origin: np.ndarray, ex: np.ndarray, ey: np.ndarray) -> np.ndarray:
    """(3, 4) affine map of scanner mm to (in-plane x, in-plane y, height above the plane)."""
    R = np.vstack([ex, ey, np.cross(ex, ey)])
    return np.hstack([R, (-R @ origin)[:, None]])


def cut(solid, M: np.ndarray):
    """The cross-section of a manifold solid by the plane z = 0 of the map M."""
    return solid.transform(M).slice(0.0)


def rv_area_outside(rv_loop: np.ndarray, lv_epi_loop: np.ndarray | None, normal: np.ndarray,
                    step: float = 0.25) -> float:
    """Area (mm²) of an RV loop outside the LV epicardial loop of the same slice (grid of
    ``step`` mm, even-odd tests)."""
    B = in_plane_basis(normal)
    c = rv_loop.mean(axis=0)
    r2 = (rv_loop - c) @ B.T
    lo, hi = r2.min(axis=0), r2.max(axis=0)
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], step) + step / 2,
                         np.arange(lo[1], hi[1], step) + step / 2)
    g = np.column_stack([gx.ravel(), gy.ravel()])
    inside = points_in_polygon(g, r2)
    if lv_epi_loop is not None:
        inside &= ~points_in_polygon(g, (lv_epi_loop - c) @ B.T)
    return float(inside.sum()) * step * step


def sa_rows(model, frame: int) -> list[dict]:
    """Per SA slice of one frame: contour and model areas (mm²) of LV cavity, LV wall and
    RV cavity, and the slice's level along the stacking direction (mm)."""
    geo = model.geometry[frame]
    sol = model.solids(frame)
    n = geo.direction
    rows = []
    for endo in geo.sections["lv_endo"]:
        sl = endo.slice
        epi = next((s for s in geo.sections.get("lv_epi", []) if s.slice == sl), None)
        rv = next((s for s in geo.sections.get("rv_endo", []) if s.slice == sl), None)
        nrm = endo.plane.normal
        o = endo.points.mean(axis=0)
        B = in_plane_basis(nrm)
        M = _frame_to_plane(o, B[0], B[1])
        row = {"slice": sl, "level": float(o @ n),
               "lv_cavity": (polygon_area(endo.points, nrm), cut(sol["lv_cavity"], M).area())}
        if epi is not None:
            row["lv_wall"] = (polygon_area(epi.points, nrm) - polygon_area(endo.points, nrm),
                              cut(sol["lv_myocardium"], M).area())
        if rv is not None:
            row["rv_cavity"] = (rv_area_outside(rv.points, None if epi is None else epi.points,
                                                nrm), cut(sol["rv_cavity"], M).area())
        rows.append(row)
    return rows


def sa_figure(model, frame: int, path: Path) -> None:
    """Each SA slice of one frame: the model's solids cut by the image plane, filled, and the
    slice's contour points."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    geo = model.geometry[frame]
    sol = model.solids(frame)
    secs = geo.sections["lv_endo"]
    fig, axes = plt.subplots(1, len(secs), figsize=(3.6 * len(secs), 4.0))
    for ax, endo in zip(np.atleast_1d(axes), secs):
        B = in_plane_basis(endo.plane.normal)
        o = endo.points.mean(axis=0)
        M = _frame_to_plane(o, B[0], B[1])
        for k, col in COLOURS.items():
            for poly in cut(sol[k], M).to_polygons():
                p = np.vstack([poly, poly[:1]])
                ax.fill(p[:, 0], p[:, 1], color=col, alpha=0.3, lw=0)
            ax.fill([], [], color=col, alpha=0.3, label=k)
        for c in model.study.contours_at(frame, view="SA"):
            if c.slice == endo.slice and c.structure in POINT_COLOURS:
                q = (c.points - o) @ B.T
                ax.plot(q[:, 0], q[:, 1], ".", ms=3, color=POINT_COLOURS[c.structure],
                        label=f"{c.structure} points")
        ax.set_aspect("equal")
        ax.set_title(f"{endo.slice}, frame {frame} (mm)", fontsize=9)
    h, lab = np.atleast_1d(axes)[0].get_legend_handles_labels()
    keep = dict(zip(lab, h))
    fig.legend(keep.values(), keep.keys(), fontsize=7, loc="lower center", ncol=5)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def level_profile(model, frame: int, key: str, step: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Cross-section area (mm²) of one solid at levels ``step`` mm apart along the stacking
    direction (planes perpendicular to it, i.e. parallel to the SA slices)."""
    n = model.geometry[frame].direction
    B = in_plane_basis(n)
    t = model.solids(frame)[key].transform(np.hstack([np.vstack([B, n]), np.zeros((3, 1))]))
    bb = t.bounding_box()
    h = np.arange(np.floor(bb[2]), np.ceil(bb[5]) + step, step)
    return h, np.array([t.slice(float(x)).area() for x in h])


def profile_figure(model, frames, path: Path, before=None) -> list[str]:
    """RV and LV cavity area against level, with the SA contour areas and the levels of the
    RV endocardium's synthetic sections (and, dashed, the RV cavity of ``before``: the model
    with ungraded RV sections every 2.5 mm, as before the grading); and a table of the RV
    cavity per slab (ours, ``before``'s, the trapezoid of the contour areas)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(frames), figsize=(6 * len(frames), 4.2), sharey=True)
    table = ["| frame | slab (levels, mm) | RV cavity: ours, graded (mL) | RV sections every "
             "2.5 mm (before; mL) | trapezoid of the SA contour areas (mL) |",
             "|---|---|---|---|---|"]
    for ax, f in zip(np.atleast_1d(axes), frames):
        rows = sa_rows(model, f)
        if before is not None:
            hb, ab = level_profile(before, f, "rv_cavity")
            ax.plot(hb, ab, color="tab:green", ls="--", lw=1.0,
                    label="rv_cavity, RV sections every 2.5 mm (before)")
            syn_b = [float(s_.points.mean(axis=0) @ model.geometry[f].direction)
                     for s_ in before.fit(f, "rv_endo").sections if s_.synthetic]
            ax.plot(syn_b, np.full(len(syn_b), -120.0), "|", color="0.5", ms=8,
                    label="its synthetic RV sections (before)")
        for key, col in (("rv_cavity", "tab:green"), ("lv_cavity", "tab:red")):
            h, a = level_profile(model, f, key)
            ax.plot(h, a, color=col, lw=1.2, label=f"{key}, ours")
            lv = [r["level"] for r in rows if key in r]
            ax.plot(lv, [r[key][0] for r in rows if key in r], "o", color=col, mfc="none",
                    label=f"{key}, SA contours")
            if key == "rv_cavity":
                step = h[1] - h[0]

                def slab(hh, aa, lo, hi):
                    return aa[(hh >= lo) & (hh < hi)].sum() * (hh[1] - hh[0]) / 1000
                for r0, r1 in zip(rows[:-1], rows[1:]):
                    if key in r0 and key in r1:
                        ours = slab(h, a, r0["level"], r1["level"])
                        old = slab(hb, ab, r0["level"], r1["level"]) if before is not None else np.nan
                        trap = 0.5 * (r0[key][0] + r1[key][0]) * (r1["level"] - r0["level"]) / 1000
                        table.append(f"| {f} | {r0['slice']}–{r1['slice']} ({r0['level']:.1f}–"
                                     f"{r1['level']:.1f}) | {ours:.1f} | {old:.1f} | {trap:.1f} |")
                first = rows[0]["level"]
                old = slab(hb, ab, -1e9, first) if before is not None else np.nan
                table.append(f"| {f} | basal of {rows[0]['slice']} (< {first:.1f}) | "
                             f"{a[h < first].sum() * step / 1000:.1f} | {old:.1f} | |")
        n = model.geometry[f].direction
        syn = [float(s.points.mean(axis=0) @ n) for s in model.fit(f, "rv_endo").sections
               if s.synthetic]
        ax.plot(syn, np.zeros(len(syn)), "|", color="tab:green", ms=12,
                label="RV endocardium: synthetic sections (graded, now)")
        ax.axvline(float(model.base_planes[f]["rv"].origin @ n), color="tab:green", ls=":",
                   lw=0.8, label="tricuspid plane (centre)")
        ax.set_xlabel("level along the stacking direction, mm (base → apex)")
        ax.set_title(f"frame {f}")
        ax.legend(fontsize=7)
    np.atleast_1d(axes)[0].set_ylabel("cross-section area, mm²")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return table


def la_rows_and_figure(model, frames, path: Path, figure_frame: int = 9) -> list[str]:
    """Per LA view: the area enclosed by its RV (LV) endocardial contour, closed across the
    annulus, against the model's RV (LV) cavity cut by that view's plane; figure of the
    views at ``figure_frame``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    st = model.study
    out = ["| frame | LA view | RV cavity: contour / ours (mm²) | LV cavity: contour / ours (mm²) |",
           "|---|---|---|---|"]
    views = sorted({c.slice for c in st.contours_at(figure_frame, view="LA")})
    fig, axes = plt.subplots(1, len(views), figsize=(4.6 * len(views), 4.8))
    for f in frames:
        sol = model.solids(f)
        for sl in sorted({c.slice for c in st.contours_at(f, view="LA")}):
            im = next(i for i in st.images if i.slice == sl and i.frame == f)
            M = _frame_to_plane(im.position, im.row_cosine, im.column_cosine)
            nrm = np.cross(im.row_cosine, im.column_cosine)
            cells = []
            for kinds, key in ((("rv_freewall", "rv_septum", "rv_endo"), "rv_cavity"),
                               (("lv_endo",), "lv_cavity")):
                parts = [c.points for c in st.contours_at(f, view="LA")
                         if c.slice == sl and c.structure in kinds]
                if not parts:
                    cells.append("")
                    continue
                a_c = polygon_area(join_open_parts(parts), nrm)
                a_m = cut(sol[key], M).area()
                cells.append(f"{a_c:.0f} / {a_m:.0f} ({100 * (a_m / a_c - 1):+.0f} %)")
            out.append(f"| {f} | {sl} | {cells[0]} | {cells[1]} |")
            if f == figure_frame:
                ax = np.atleast_1d(axes)[views.index(sl)]
                for k, col in COLOURS.items():
                    for poly in cut(sol[k], M).to_polygons():
                        p = np.vstack([poly, poly[:1]])
                        ax.fill(p[:, 0], p[:, 1], color=col, alpha=0.3, lw=0)
                    ax.fill([], [], color=col, alpha=0.3, label=k)
                pts = []
                for c in st.contours_at(f, view="LA"):
                    if c.slice == sl and c.structure in POINT_COLOURS:
                        q = (c.points - im.position) @ np.vstack([im.row_cosine, im.column_cosine]).T
                        pts.append(q)
                        ax.plot(q[:, 0], q[:, 1], ".", ms=3, color=POINT_COLOURS[c.structure],
                                label=f"{c.structure} points")
                q = np.concatenate(pts)
                ax.set_xlim(q[:, 0].min() - 12, q[:, 0].max() + 12)
                ax.set_ylim(q[:, 1].max() + 12, q[:, 1].min() - 12)
                ax.set_aspect("equal")
                ax.set_title(f"{sl}, frame {f} (mm in the image)", fontsize=9)
    h, lab = [], []
    for ax in np.atleast_1d(axes):
        for hh, lb in zip(*ax.get_legend_handles_labels()):
            if lb not in lab:
                h.append(hh)
                lab.append(lb)
    fig.legend(h, lab, fontsize=7, loc="lower center", ncol=5)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return out


def basal_ring_rows(model, frames) -> tuple[list[str], dict]:
    """The LV wall a basal ring beyond the mitral plane would add (table; grams per frame):
    the LA epicardial points beyond the plane (how many, how far) and the wall between the model's untrimmed LV
    epi- and endocardial solids in the slab from the plane to the farthest such point."""
    out = ["| frame | LA lv_epi points beyond the mitral plane (of all) | farthest per view (mm) "
           "| wall in that slab (mL; g at 1.05 g/mL) |", "|---|---|---|---|"]
    grams = {}
    for f in frames:
        geo = model.geometry[f]
        pl = model.base_planes[f]["lv"]
        far, beyond, total = [], 0, 0
        for sl, p in zip(geo.la_slices["lv_epi"], geo.la_points["lv_epi"]):
            h = pl.signed_distance(p)
            total += len(p)
            beyond += int((h < 0).sum())
            far.append(f"{sl} {max(0.0, -float(h.min())):.1f}")
        H = max(0.0, -min(float(pl.signed_distance(p).min()) for p in geo.la_points["lv_epi"]))
        wall = model._solid(f, "lv_epi") - model._solid(f, "lv_endo")
        lev = float(pl.origin @ pl.normal)
        ring = wall.trim_by_plane(-pl.normal, -lev).trim_by_plane(pl.normal, lev - H)
        v = ring.volume() / 1000
        out.append(f"| {f} | {beyond} of {total} | {', '.join(far)} | {v:.1f}; {1.05 * v:.1f} |")
        grams[f] = 1.05 * v
    return out, grams


def septum_rule_rows(study, model, frames) -> list[str]:
    """LV myocardium with the LV epicardial arcs closed through the RV septum (the rule)
    and, as before it, spanned across the septum by the loop's spline."""
    with spline_across_septum():
        before = reconstruct(study, frames=list(frames))
        vb = {f: dict(before.volumes[f]) for f in frames}
    out = ["| frame | LV myocardium: spline across the septum (before) | closed through the RV "
           "septum (now) | RV cavity before / now (mL) |", "|---|---|---|---|"]
    for f in frames:
        a, b = vb[f], model.volumes[f]
        out.append(f"| {f} | {a['lv_myocardium']:.1f} mL ({1.05 * a['lv_myocardium']:.1f} g) | "
                   f"{b['lv_myocardium']:.1f} mL ({1.05 * b['lv_myocardium']:.1f} g) | "
                   f"{a['rv_cavity']:.1f} / {b['rv_cavity']:.1f} |")
    return out


def sa_table(model, frames) -> list[str]:
    out = ["| frame | slice | level (mm) | LV cavity: contour / ours (mm²) | LV wall: contour / ours "
           "| RV cavity: contour / ours |", "|---|---|---|---|---|---|"]
    for f in frames:
        for r in sa_rows(model, f):
            cells = [f"{r[k][0]:.0f} / {r[k][1]:.0f}" if k in r else ""
                     for k in ("lv_cavity", "lv_wall", "rv_cavity")]
            out.append(f"| {f} | {r['slice']} | {r['level']:.1f} | " + " | ".join(cells) + " |")
    return out


def half_spacing_step(fraction: float = 0.5, least_mm: float = 2.5):
    """A patch (tried in session 6, not adopted): synthetic sections of every surface every
    ``fraction`` of the median SA slice spacing, at least ``least_mm``, ungraded."""
    from cardionurbs.anatomy import surfaces
    plain = surfaces.synthetic_sections

    def step(secs, direction):
        levels = np.array([float(sec.points.mean(axis=0) @ direction) for sec in secs])
        if len(levels) < 2:
            return least_mm
        return max(least_mm, fraction * float(np.median(np.abs(np.diff(levels)))))

    def synthetic_sections(geo, structure, secs, apex):
        # the step of the sections built from LA crossings (the tapered ends keep theirs)
        if not geo.la_points.get(structure) or not secs:
            return plain(geo, structure, secs, apex)
        with mock.patch.object(surfaces, "SYNTHETIC_STEP_MM", step(secs, geo.direction)):
            return plain(geo, structure, secs, apex)
    return _patches(mock.patch.object(surfaces, "synthetic_sections", synthetic_sections),
                    mock.patch.object(surfaces, "GRADED_STRUCTURES", ()))


def graded(structures=("rv_endo", "rv_epi"), ratio: float | None = None):
    """A patch: the synthetic sections of ``structures`` graded next to the SA stack
    (:func:`cardionurbs.anatomy.surfaces.synthetic_offsets`) with ``ratio`` (None: the
    default); ``structures=()``: every surface every 2.5 mm (as before the rule)."""
    from cardionurbs.anatomy import surfaces
    ps = [mock.patch.object(surfaces, "GRADED_STRUCTURES", tuple(structures))]
    if ratio is not None:
        ps.append(mock.patch.object(surfaces, "GRADING_RATIO", float(ratio)))
    return _patches(*ps)


@contextmanager
def _patches(*ps):
    """Several patches (context managers) entered together."""
    with ExitStack() as stack:
        for p in ps:
            stack.enter_context(p)
        yield


def spline_across_septum():
    """A patch: open LV epicardial arcs closed by the loop's spline (as before the rule)."""
    return mock.patch.object(sections_module, "is_open_arc", lambda points: False)


BIVME = {(24, "lv_cavity"): 179.0, (24, "rv_cavity"): 167.8, (24, "lv_myocardium"): 131.3,
         (24, "rv_myocardium"): 51.9, (9, "lv_cavity"): 72.0, (9, "rv_cavity"): 76.7}


def _cells(volumes, frames_keys=BIVME) -> list[str]:
    cells = []
    for (f, k), ref in frames_keys.items():
        x = volumes[f][k] * (1.05 if "myocardium" in k else 1.0)
        cells.append(f"{x:.1f} ({100 * (x / ref - 1):+.1f} %)")
    return cells


def step_by_step(study, model, frames) -> tuple[list[str], list[str], object]:
    """bivme-patient1 against biv-me before the septum rule, with it (RV sections every 2.5 mm,
    as before the grading), and now (RV sections graded); then the variants of the grading
    tried beside it (its ratio, the LV graded as well, the earlier half-spacing rule). Returns
    the two tables and the model without the grading."""
    def volumes(*patches):
        with _patches(*patches):
            m = reconstruct(study, frames=list(frames))
            return m, {f: dict(m.volumes[f]) for f in frames}
    _, vb = volumes(spline_across_septum(), graded(()))
    ungraded, vu = volumes(graded(()))
    now = {f: model.volumes[f] for f in frames}
    out = ["| frame | quantity | biv-me | before: spline across the septum, sections every 2.5 mm "
           "| + LV epicardium through the RV septum | + RV sections graded next to the SA stack "
           "(now) |", "|---|---|---|---|---|---|"]
    cols = [_cells(v) for v in (vb, vu, now)]
    for i, ((f, k), ref) in enumerate(BIVME.items()):
        mass = "myocardium" in k
        out.append(f"| {f} | {k}{' mass (g)' if mass else ' (mL)'} | {ref} | "
                   + " | ".join(c[i] for c in cols) + " |")
    variants = [("graded, ratio 2 (now)", now)]
    for label, patch in (("graded, ratio 1.5", graded(ratio=1.5)),
                         ("graded, ratio 3", graded(ratio=3.0)),
                         ("graded, ratio 4", graded(ratio=4.0)),
                         ("graded, ratio 2, LV surfaces graded too",
                          graded(("lv_endo", "lv_epi", "rv_endo", "rv_epi"))),
                         ("every surface every half slice spacing (session 6, not adopted)",
                          half_spacing_step()),
                         ("every surface every 2.5 mm (before)", None)):
        variants.append((label, vu if patch is None else volumes(patch)[1]))
    var = ["| synthetic sections | " + " | ".join(
        f"{f} {k.replace('_cavity', '').replace('_myocardium', ' mass')}" for f, k in BIVME) + " |",
        "|---|" + "---|" * len(BIVME)]
    for label, v in variants:
        var.append(f"| {label} | " + " | ".join(
            c.split(" (")[1].rstrip(")") for c in _cells(v)) + " |")
    return out, var, ungraded


def gap_minima(model, frame: int) -> list[tuple[str, str, float, float]]:
    """Per pair of neighbouring SA slices: (slice, slice, the smallest RV cavity cross-section
    between them (mm², planes parallel to the slices, every 0.5 mm), the smaller of the two
    slices' RV contour areas)."""
    rows = [r for r in sa_rows(model, frame) if "rv_cavity" in r]
    h, a = level_profile(model, frame, "rv_cavity")
    out = []
    for r0, r1 in zip(rows[:-1], rows[1:]):
        inside = (h > r0["level"]) & (h < r1["level"])
        out.append((r0["slice"], r1["slice"], float(a[inside].min()),
                    min(r0["rv_cavity"][0], r1["rv_cavity"][0])))
    return out


def where_section(study, root: Path, frames=(24, 9)) -> tuple[object, dict]:
    """Tables and figures of where the model differs (lines for the report; the model)."""
    model = reconstruct(study, frames=list(frames))
    steps, variants, ungraded = step_by_step(study, model, frames)
    ring, ring_g = basal_ring_rows(model, frames)
    parts = {
        "steps": steps,
        "variants": variants,
        "septum": septum_rule_rows(study, model, frames),
        "sa": sa_table(model, frames),
        "ring": ring,
        "ring_g": ring_g,
        "profile": profile_figure(model, frames, root / PROFILE_FIGURE, before=ungraded),
        "la": la_rows_and_figure(model, frames, root / LA_FIGURE),
        "minima": {f: (gap_minima(model, f), gap_minima(ungraded, f)) for f in frames},
    }
    sa_figure(model, frames[0], root / SA_FIGURE)
    return model, parts
