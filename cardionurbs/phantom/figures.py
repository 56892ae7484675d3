"""Figures of phantom images with their annotations (paper Fig. 1 style), matplotlib Agg.

``python -m cardionurbs.phantom.figures OUT_DIR [COHORT.toml]`` writes, for each preset
(seed 0), ``phantom_<preset>_ed.png`` and ``phantom_<preset>_es.png``: the
mid-ventricular tagged SA image at ED and ES, cropped around the heart, with
the LV/RV contours and the tracked tag lines drawn over it; with a cohort
spec it also prints the markdown table of its subjects' truth metrics.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

COLORS = {"lv_endo": "#e41a1c", "lv_epi": "#4daf4a", "rv_endo": "#377eb8", "rv_epi": "#ff7f00"}


def mid_sa_slice(phantom) -> str:
    """The SA slice used for EI (mid-ventricular at ES), else the middle of the stack.

    Parameters
    ----------
    phantom : cardionurbs.phantom.generate.Phantom
        A generated phantom.

    Returns
    -------
    str
        The SA slice id.
    """
    sid = phantom.truth.get("tags", {}).get("ei_slice")
    if sid:
        return sid
    sa = sorted({im.slice for im in phantom.study.images if im.view == "SA"})
    return sa[len(sa) // 2]


def plot_sa_frame(phantom, slice_id: str, frame: int, path: str | Path, title: str | None = None,
                  noise: bool = True) -> Path:
    """Save the tagged SA image of one slice and frame with contours and tag lines (PNG).

    Parameters
    ----------
    phantom : cardionurbs.phantom.generate.Phantom
        A generated phantom.
    slice_id : str
        The SA slice.
    frame : int
        The frame index, 0-based.
    path : path-like
        The PNG to write (its folder is made).
    title : str or None, optional
        The title (default subject, slice and frame).
    noise : bool, optional
        Render the image with noise (seeded by the frame).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cardionurbs.phantom.dicom import render_image

    st = phantom.study
    im = [p for p in st.images if p.slice == slice_id and p.frame == frame][0]
    rng = np.random.default_rng(frame) if noise else None
    img = render_image(phantom, im, rng)
    conts = [c for c in st.contours if c.image == im.id]
    tags = [t for t in st.tags if t.image == im.id]
    allpix = np.concatenate([im.scanner_to_pixel(c.points) for c in conts])
    lo, hi = allpix.min(axis=0) - 18, allpix.max(axis=0) + 18
    fig, ax = plt.subplots(figsize=(5.2, 5.2), dpi=110)
    ax.imshow(img, cmap="gray", vmin=0, vmax=1.1, interpolation="nearest")
    for t in tags:
        q = im.scanner_to_pixel(t.points)
        ax.plot(q[:, 0], q[:, 1], ".", ms=1.6, color="#ffff33" if t.family == "sa1" else "#ff33ff")
    for c in conts:
        q = im.scanner_to_pixel(c.points)
        q = np.vstack([q, q[:1]]) if c.closed else q
        ax.plot(q[:, 0], q[:, 1], "-", lw=1.3, color=COLORS.get(c.structure, "w"), label=c.structure)
    for name, structure in (("LV", "lv_endo"), ("RV", "rv_endo")):
        c = [c for c in conts if c.structure == structure]
        if c:
            q = im.scanner_to_pixel(c[0].points).mean(axis=0)
            ax.text(q[0], q[1], name, color="w", ha="center", va="center", fontsize=11, weight="bold")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(hi[1], lo[1])
    ax.set_xticks([])
    ax.set_yticks([])
    ax.legend(loc="lower right", fontsize=7, framealpha=0.6)
    ax.set_title(title or f"{st.subject} {slice_id} frame {frame}", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def write_preset_figures(out_dir: str | Path, seed: int = 0, frames: int = 20) -> list[Path]:
    """ED and ES mid-ventricular figures for every preset (see the module docstring).

    Parameters
    ----------
    out_dir : path-like
        The folder the PNGs go to (``phantom_<preset>_ed.png``, ``_es.png``).
    seed : int, optional
        The phantoms' seed.
    frames : int, optional
        Frames per cycle.

    Returns
    -------
    list of pathlib.Path
        The PNGs written.
    """
    from cardionurbs.phantom.generate import generate
    from cardionurbs.phantom.presets import PATHOLOGIES

    out = []
    for p in PATHOLOGIES:
        ph = generate(p, seed=seed, frames=frames, volume_check=False)
        sid = mid_sa_slice(ph)
        for label, fr in (("ed", 0), ("es", ph.es_frame)):
            title = f"{p} (seed {seed}), {sid}, {label.upper()} (frame {fr})"
            out.append(plot_sa_frame(ph, sid, fr, Path(out_dir) / f"phantom_{p}_{label}.png", title))
    return out


TABLE_COLUMNS = ("LVEDV (mL)", "LVEF (%)", "LVM (g)", "RVEDV (mL)", "RVEF (%)", "RVM (g)",
                 "MR RegFrac (%)", "RV/LV EDV ratio", "RV/LV mass ratio", "EI ES", "Twist (deg)",
                 "Twist 2D (deg)", "Torsion (deg/cm)", "LS (%)")


def cohort_truth_table(spec_path: str | Path) -> str:
    """Markdown table of the truth metrics of every subject of a cohort spec.

    Parameters
    ----------
    spec_path : path-like
        A cohort spec (TOML, :func:`cardionurbs.phantom.presets.load_cohort_spec`).

    Returns
    -------
    str
        The Markdown table: subject, pathology, HR (bpm) and :data:`TABLE_COLUMNS` (mL, %, g,
        deg, deg/cm).
    """
    from cardionurbs.phantom.generate import generate
    from cardionurbs.phantom.presets import load_cohort_spec

    rows = ["| subject | pathology | HR | " + " | ".join(TABLE_COLUMNS) + " |",
            "|---" * (3 + len(TABLE_COLUMNS)) + "|"]
    for s in load_cohort_spec(spec_path):
        m = generate(s.pathology, seed=s.seed, frames=s.frames, subject=s.id,
                     volume_check=False).truth["metrics"]
        rows.append(f"| {s.id} | {s.pathology} | {m['HR (bpm)']:.0f} | "
                    + " | ".join(f"{m[c]:.2f}" if "ratio" in c or c == "EI ES" else f"{m[c]:.1f}"
                                 for c in TABLE_COLUMNS) + " |")
    return "\n".join(rows)


if __name__ == "__main__":  # pragma: no cover
    for path in write_preset_figures(sys.argv[1] if len(sys.argv) > 1 else "reports/figures"):
        print(path)
    if len(sys.argv) > 2:
        print(cohort_truth_table(sys.argv[2]))
