"""Static figures of one analysed study (paper Figs. 3-10), headless PNG.

Every figure is a bare :class:`matplotlib.figure.Figure` saved as PNG by the
Agg renderer: no pyplot, no global backend switch, no display needed. 3D
panels show tessellated NURBS surfaces (:func:`cardionurbs.nurbs.tessellate`)
as ONE depth-sorted :class:`~mpl_toolkits.mplot3d.art3d.Poly3DCollection` per
panel, so translucent walls and the surfaces inside them sort together
(painter's algorithm over all triangles of the panel).

Conventions
-----------
* Axes are scanner (patient LPS) millimetres with equal scale on x, y, z;
  an orientation marker draws the anterior (−y), left (+x) and head (+z)
  directions from a corner of the box.
* Camera: perpendicular to the LV long axis (apex → mitral centre, ED), with
  the base at the top; it looks along the septal plane, so the RV sits beside
  the LV as in a four-chamber view (from the anterior side). Without an RV the
  camera looks from the anterior direction.
* Colours: Okabe–Ito colour-blind-safe palette (:data:`OKABE_ITO`); faces are
  Lambert-shaded by scaling their RGB (two-sided light), so a structure's hue
  is kept in the PNG.
* Every figure carries a caption naming the subject, frame(s) and structure.

A figure whose input is missing (no tag lines, one frame only, no RV, no
truth) is left out with one line saying why (:attr:`FigureSet.skipped`, and
``skipped.txt`` beside the PNGs); it never raises.

Public API: :func:`write_figures`, :func:`render_figures`.
"""

from __future__ import annotations

import json
import math
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import matplotlib.colors
import matplotlib.ticker
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import FancyArrowPatch
from mpl_toolkits.mplot3d import proj3d
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from cardionurbs.safe import plain_text
from cardionurbs import nurbs
from cardionurbs.heap import acyclic
from cardionurbs.io import atomic
from cardionurbs.report.bullseye import QUANTITIES as BULLSEYE_QUANTITIES, BullseyeCanvas, quantity_figure

__all__ = ["write_figures", "render_figures", "FigureSet", "FigureResult", "OKABE_ITO",
           "STRUCTURE_COLOURS", "FAMILY_COLOURS", "FLAG_COLOUR", "tag_data", "view_frame"]

# Okabe & Ito (2008), "Color Universal Design"
OKABE_ITO = {
    "black": "#000000", "orange": "#E69F00", "sky_blue": "#56B4E9", "bluish_green": "#009E73",
    "yellow": "#F0E442", "blue": "#0072B2", "vermillion": "#D55E00", "reddish_purple": "#CC79A7",
}
STRUCTURE_COLOURS = {"lv_endo": OKABE_ITO["vermillion"], "lv_epi": OKABE_ITO["orange"],
                     "rv_endo": OKABE_ITO["blue"], "rv_epi": OKABE_ITO["sky_blue"]}
FAMILY_COLOURS = {"sa1": OKABE_ITO["bluish_green"], "sa2": OKABE_ITO["reddish_purple"],
                  "la": OKABE_ITO["yellow"]}
FLAG_COLOUR = OKABE_ITO["vermillion"]
GOOD_LINE_COLOUR = OKABE_ITO["blue"]
NAMES = {"lv_endo": "LV endocardium", "lv_epi": "LV epicardium", "rv_endo": "RV endocardium",
         "rv_epi": "RV epicardium", "sa1": "SA tag family 1", "sa2": "SA tag family 2",
         "la": "LA tag family"}
SURFACE_GRID = (40, 14)          # (nu, nv) tessellation of a wall surface for figures
TAG_GRID = (14, 8)               # (nu, nv) tessellation of a tag surface
DPI = 100
LIGHT = np.array([0.35, -0.45, 0.82])


# ----------------------------------------------------------------- results
@dataclass
class FigureResult:
    """One written figure: file, caption, and the opaque colours it must show.

    Attributes
    ----------
    name : str
        The figure's name (``"fig03_lv_endo_ed_es"``), also its file stem.
    path : pathlib.Path
        The PNG written.
    caption : str
        Its caption.
    colours : dict of str to str
        Label -> hex colour of every opaque face or line the PNG must show (checked by the
        figure tests).
    legend_boxes : list of tuple of float
        Pixel boxes (x0, y0, x1, y1; origin top-left) of the legends in the PNG.
    """

    name: str
    path: Path
    caption: str
    colours: dict[str, str] = field(default_factory=dict)   # label -> hex (opaque faces/lines)
    legend_boxes: list[tuple[float, float, float, float]] = field(default_factory=list)
    # pixel boxes (x0, y0, x1, y1; origin top-left) of the legends in the PNG


@dataclass
class FigureSet:
    """Figures of one study: written ones, and one-line reasons for those left out.

    Attributes
    ----------
    figures : list of FigureResult
        The figures written, in drawing order.
    skipped : dict of str to str
        Figure name -> the one-line reason it was left out.
    report_tags : dict or None
        The content of ``report_tags.json`` (None without tag surfaces).
    paths : list of pathlib.Path
        The PNG files of :attr:`figures`.
    """

    figures: list[FigureResult] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    #: the content of ``report_tags.json``, arrays as numpy arrays (None without tag surfaces)
    report_tags: dict | None = None

    @property
    def paths(self) -> list[Path]:
        return [f.path for f in self.figures]


# ----------------------------------------------------------------- geometry
def _rgb(hex_colour: str) -> np.ndarray:
    return np.asarray(matplotlib.colors.to_rgb(hex_colour))


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else v


def lambert_colours(vertices: np.ndarray, faces: np.ndarray, colour: str, alpha: float = 1.0
                    ) -> np.ndarray:
    """RGBA per face: the colour scaled by 0.55 + 0.45 |n · l| (two-sided Lambert, unit
    face normal n, fixed light l); hue is preserved, only brightness changes.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        Mesh vertices, in mm.
    faces : ndarray of int, shape (F, 3)
        Vertex indices of each triangle.
    colour : str
        The base colour (hex or matplotlib name).
    alpha : float, optional
        Opacity of every face, 0 to 1.

    Returns
    -------
    ndarray, shape (F, 4)
        RGBA per face, each in [0, 1].
    """
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
    k = 0.55 + 0.45 * np.abs(n @ _unit(LIGHT))
    rgba = np.empty((len(faces), 4))
    rgba[:, :3] = np.clip(k[:, None] * _rgb(colour)[None, :], 0, 1)
    rgba[:, 3] = alpha
    return rgba


@dataclass
class View:
    """Camera of a 3D panel: matplotlib (elev, azim, roll) in degrees and the data box.

    Attributes
    ----------
    elev, azim, roll : float
        matplotlib's camera angles, in degrees.
    centre : ndarray, shape (3,)
        Centre of the data box, in mm.
    half : float
        Half the side of the (cubic) data box, in mm.
    """

    elev: float
    azim: float
    roll: float
    centre: np.ndarray
    half: float


def view_frame(axis: tuple[np.ndarray, np.ndarray], side: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """(w, up): unit view direction (centre → eye) perpendicular to the long axis and the
    screen-up direction (apex → base).

    ``side`` (e.g. RV centroid − LV centroid) is kept in the screen plane: w ⟂ side
    and w ⟂ axis, with w chosen on the anterior side (w · (0, −1, 0) ≥ 0, LPS).
    Without ``side``, w is the anterior direction made perpendicular to the axis.

    Parameters
    ----------
    axis : tuple of (ndarray, ndarray)
        The LV long axis (apex (3,), base centre (3,)), in mm (scanner coordinates).
    side : ndarray, shape (3,), optional
        A direction kept in the screen plane (RV centroid − LV centroid).

    Returns
    -------
    w : ndarray, shape (3,)
        Unit view direction, centre to eye.
    up : ndarray, shape (3,)
        Unit screen-up direction, apex to base.
    """
    apex, base = (np.asarray(a, float) for a in axis)
    up = _unit(base - apex)
    anterior = np.array([0.0, -1.0, 0.0])
    w = None
    if side is not None:
        s = side - (side @ up) * up
        if np.linalg.norm(s) > 1e-6:
            w = _unit(np.cross(up, _unit(s)))
    if w is None:
        w = anterior - (anterior @ up) * up
        if np.linalg.norm(w) < 1e-6:
            w = np.array([1.0, 0.0, 0.0]) - up[0] * up
        w = _unit(w)
    if w @ anterior < 0:
        w = -w
    return w, up


def _camera(w: np.ndarray, up: np.ndarray, centre: np.ndarray, half: float) -> View:
    """matplotlib angles putting the eye along ``w`` with ``up`` vertical on screen.

    elev = asin(w_z), azim = atan2(w_y, w_x); the roll is found by projection: with
    roll 0 the screen direction of ``up`` makes an angle α with the screen x axis, and
    the roll ±(90° − α) that makes it point straight up is kept (the sign is checked
    by projecting again, so no convention — including the eye on the z axis — is
    assumed).
    """
    elev = math.degrees(math.asin(float(np.clip(w[2], -1, 1))))
    azim = math.degrees(math.atan2(w[1], w[0]))
    upp = _unit(up - (up @ w) * w)

    def screen_angle(roll: float) -> float:
        ax = _probe_axes()
        ax.view_init(elev=elev, azim=azim, roll=roll)
        M = ax.get_proj()
        x0, y0, _ = proj3d.proj_transform(0.0, 0.0, 0.0, M)
        x1, y1, _ = proj3d.proj_transform(*(0.5 * upp), M)
        return math.degrees(math.atan2(y1 - y0, x1 - x0))

    alpha = screen_angle(0.0)
    roll = 90.0 - alpha
    if abs(((screen_angle(roll) - 90.0) + 180.0) % 360.0 - 180.0) > 1e-3:
        roll = alpha - 90.0
    roll = (roll + 180.0) % 360.0 - 180.0
    return View(elev, azim, roll, np.asarray(centre, float), float(half))


_PROBE: list = []


def _probe_axes():
    """A cached unit-cube 3D axes used only to project directions (camera set-up)."""
    if not _PROBE:
        ax = Figure(figsize=(2, 2)).add_subplot(projection="3d")
        ax.set_xlim(-1, 1), ax.set_ylim(-1, 1), ax.set_zlim(-1, 1)
        ax.set_box_aspect((1, 1, 1))
        _PROBE.append(ax)
    return _PROBE[0]


@dataclass
class Mesh:
    """A triangle mesh to draw: vertices (V, 3) mm, faces (F, 3), colour, alpha, label.

    Attributes
    ----------
    vertices : ndarray, shape (V, 3)
        Vertices, in mm.
    faces : ndarray of int, shape (F, 3)
        Vertex indices of each triangle.
    colour : str
        Face colour (hex).
    alpha : float
        Opacity, 0 to 1.
    label : str
        The legend label.
    """

    vertices: np.ndarray
    faces: np.ndarray
    colour: str
    alpha: float = 1.0
    label: str = ""


def surface_mesh(surface: Any, colour: str, alpha: float = 1.0, label: str = "",
                 grid: tuple[int, int] = SURFACE_GRID) -> Mesh:
    """Tessellate a NURBS surface (``nu x nv`` grid) into a :class:`Mesh`.

    Parameters
    ----------
    surface : cardionurbs.nurbs.NurbsSurface
        The surface (control points in mm).
    colour : str
        Face colour (hex).
    alpha : float, optional
        Opacity, 0 to 1.
    label : str, optional
        The legend label.
    grid : tuple of (int, int), optional
        Samples (nu, nv) of the tessellation (default :data:`SURFACE_GRID`).

    Returns
    -------
    Mesh
        The triangles, vertices in mm.
    """
    v, f = nurbs.tessellate(surface, *grid)
    return Mesh(np.asarray(v, float), np.asarray(f, np.int64), colour, alpha, label)


def _bounds(points: Sequence[np.ndarray]) -> tuple[np.ndarray, float]:
    P = np.concatenate([np.asarray(p, float).reshape(-1, 3) for p in points])
    lo, hi = P.min(axis=0), P.max(axis=0)
    return (lo + hi) / 2, float((hi - lo).max()) / 2 * 1.05 + 1.0


def draw_panel(ax, meshes: Sequence[Mesh], view: View, *, lines: Sequence[tuple] = (),
               title: str = "", marker: bool = True) -> None:
    """Draw meshes (one depth-sorted collection) and polylines on a 3D axes.

    ``lines``: (points (n, 3), colour, width) polylines drawn on top of the surfaces.

    Parameters
    ----------
    ax : mpl_toolkits.mplot3d.Axes3D
        The 3D axes drawn on.
    meshes : sequence of Mesh
        The surfaces, drawn as one depth-sorted collection.
    view : View
        The camera and data box.
    lines : sequence of tuple, optional
        (points (n, 3) in mm, colour, line width in pt) polylines drawn on top.
    title : str, optional
        The panel's title.
    marker : bool, optional
        Draw the orientation arrows (:func:`orientation_marker`).
    """
    polys, colours = [], []
    for m in meshes:
        if len(m.faces) == 0:
            continue
        polys.append(m.vertices[m.faces])
        colours.append(lambert_colours(m.vertices, m.faces, m.colour, m.alpha))
    if polys:
        fc = np.concatenate(colours)
        ec = fc.copy()                     # edges in the face colour hide anti-aliasing seams
        ec[:, 3] = np.where(fc[:, 3] >= 1.0, 1.0, 0.0)
        pc = Poly3DCollection(np.concatenate(polys), facecolors=fc, edgecolors=ec,
                              linewidths=0.35, shade=False)
        pc.set_zorder(1)
        ax.add_collection3d(pc)
    if lines:
        lc = Line3DCollection([np.asarray(p, float) for p, _, _ in lines],
                              colors=[c for _, c, _ in lines], linewidths=[w for _, _, w in lines])
        lc.set_zorder(3)
        ax.add_collection3d(lc)
    c, h = view.centre, view.half
    ax.set_xlim(c[0] - h, c[0] + h)
    ax.set_ylim(c[1] - h, c[1] + h)
    ax.set_zlim(c[2] - h, c[2] + h)
    ax.set_box_aspect((1, 1, 1), zoom=0.95)     # the axis box and its labels stay in the panel at any view
    ax.computed_zorder = False
    ax.view_init(elev=view.elev, azim=view.azim, roll=view.roll)
    ax.set_xlabel("x (mm)", fontsize=7, labelpad=5)
    ax.set_ylabel("y (mm)", fontsize=7, labelpad=5)
    ax.set_zlabel("z (mm)", fontsize=7, labelpad=5)
    ax.tick_params(labelsize=6, pad=-2)
    for a in (ax.xaxis, ax.yaxis, ax.zaxis):
        a.set_pane_color((1, 1, 1, 0))
        a.set_major_locator(matplotlib.ticker.MaxNLocator(3))
    if title:
        b = ax.get_position()            # placed above the axes' labels when saved (_save)
        ax._cn_title = ax.figure.text(b.x0 + b.width / 2, b.y1 + 0.01, plain_text(title),
                                      fontsize=9, ha="center", va="bottom")
    ax.grid(False)
    if marker:
        orientation_marker(ax)


def orientation_marker(ax) -> None:
    """Inset arrows (upper-left of a 3D panel, clear of the axis labels below) for the
    anterior (−y), left (+x) and head
    (+z) directions (LPS), projected with the panel's own camera; an arrow's length is
    its projected length relative to the longest of the three (short = toward the eye).

    Parameters
    ----------
    ax : mpl_toolkits.mplot3d.Axes3D
        A 3D panel whose camera is set.
    """
    M = ax.get_proj()
    origin = np.array(proj3d.proj_transform(0.0, 0.0, 0.0, M)[:2])
    span = float(np.diff(ax.get_xlim3d())[0]) * 0.2
    dirs = (((0.0, -1.0, 0.0), "A"), ((1.0, 0.0, 0.0), "L"), ((0.0, 0.0, 1.0), "H"))
    vec = np.array([np.array(proj3d.proj_transform(*(np.asarray(d) * span), M)[:2]) - origin
                    for d, _ in dirs])
    vec /= max(float(np.linalg.norm(vec, axis=1).max()), 1e-12)
    fig = ax.figure
    pos = ax.get_position()
    strip = MARKER_STRIP / (1 - MARKER_STRIP) * pos.width      # the free strip left of the axes
    size = 0.9 * min(strip, 0.2 * pos.height * fig.get_figheight() / fig.get_figwidth())
    h_fig = size * fig.get_figwidth() / fig.get_figheight()
    x0, y0 = pos.x0 - strip + 0.05 * strip, pos.y0 + 0.95 * pos.height - h_fig

    def at(p) -> tuple[float, float]:
        """A point of the marker's square (-1.45 .. 1.45 each way) in figure coordinates:
        the arrows are drawn on the figure itself, not on an inset axes of their own
        (an axes with its ticks costs more to make than the arrows to draw)."""
        return (x0 + (p[0] + 1.45) / 2.9 * size, y0 + (p[1] + 1.45) / 2.9 * h_fig)

    units = vec / np.maximum(np.linalg.norm(vec, axis=1, keepdims=True), 1e-9)
    spots = _spread(vec + 0.3 * units, 0.6)
    for v, spot, (_, txt) in zip(vec, spots, dirs):
        fig.add_artist(FancyArrowPatch(at((0.0, 0.0)), at(v), transform=fig.transFigure,
                                       arrowstyle="-|>", mutation_scale=10, lw=1.1,
                                       color="black", shrinkA=0, shrinkB=0))
        fig.text(*at(spot), txt, fontsize=7, fontweight="bold", ha="center", va="center")


def _spread(points: np.ndarray, gap: float) -> np.ndarray:
    """Label positions (k, 2) pushed apart pairwise until no two are closer than ``gap``
    (the marker's letters of two nearly parallel arrows would print on each other)."""
    p = np.array(points, float)
    for _ in range(10):
        moved = False
        for i in range(len(p)):
            for j in range(i + 1, len(p)):
                d = p[j] - p[i]
                n = float(np.linalg.norm(d))
                if n < gap:
                    u = d / n if n > 1e-9 else np.array([1.0, 0.0])
                    p[i] -= 0.5 * (gap - n) * u
                    p[j] += 0.5 * (gap - n) * u
                    moved = True
        if not moved:
            break
    return p


#: share of a 3-D panel's width kept free, left of its axes, for the orientation marker
MARKER_STRIP = 0.16


def _new_figure(n_panels: int, caption: str, *, width: float = 4.6, height: float = 4.8,
                three_d: bool = True) -> tuple[Figure, list]:
    fig = Figure(figsize=(width * n_panels, height), dpi=DPI)
    axes = [fig.add_subplot(1, n_panels, i + 1, projection="3d" if three_d else None)
            for i in range(n_panels)]
    chars = int(width * n_panels * 17)          # ~17 characters per inch at 7.5 pt
    text = plain_text(textwrap.fill(caption, chars))
    # the caption's height (7.5 pt lines, 1.3 line spacing) plus room for the lowest axis
    # and tick labels above it: the axes start above the caption, never on it
    caption_h = (text.count("\n") + 1) * 7.5 * 1.3 / 72.0 / height + 0.02
    fig.subplots_adjust(left=0.02 if three_d else 0.1, right=0.93 if three_d else 0.88,
                        top=0.85 if three_d else 0.93,
                        bottom=caption_h + (0.12 if three_d else 0.13),
                        wspace=0.15 if three_d else 0.3)
    fig.text(0.01, 0.01, text, fontsize=7.5, ha="left", va="bottom")
    if three_d:                 # a strip left of each 3-D axes for the orientation marker
        for ax in axes:
            b = ax.get_position()
            ax.set_position((b.x0 + MARKER_STRIP * b.width, b.y0, (1 - MARKER_STRIP) * b.width,
                             b.height))
    return fig, axes


def _legend(fig: Figure, items: Sequence[tuple[str, str]]) -> None:
    from matplotlib.patches import Patch
    fig.legend(handles=[Patch(facecolor=c, label=l) for l, c in items], loc="upper center",
               fontsize=7, frameon=False, ncol=min(len(items), 6))


def _place_titles(fig: Figure) -> None:
    """Move each 3-D panel's title just above everything its axes draw (a 3-D axis label
    can stand above the axes box, depending on the view)."""
    titled = [ax for ax in fig.axes if getattr(ax, "_cn_title", None) is not None]
    if not titled:
        return
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    canvas = fig.canvas if hasattr(fig.canvas, "get_renderer") else FigureCanvasAgg(fig)
    renderer = canvas.get_renderer()
    H = fig.get_figheight() * fig.dpi
    for ax in titled:
        top = ax.get_tightbbox(renderer).y1 / H
        ax._cn_title.set_y(max(top, ax.get_position().y1) + 4.0 / H)


def _save(fig: Figure, path: Path) -> tuple[Path, list]:
    """Render to PNG (atomic write); return the path and the legends' pixel boxes."""
    import io
    _place_titles(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    atomic.write_bytes(path, buf.getvalue())
    H = fig.get_figheight() * DPI
    boxes = []
    legends = list(fig.legends) + [a.get_legend() for a in fig.axes if a.get_legend()]
    for leg in legends:
        e = leg.get_window_extent()
        boxes.append((float(e.x0), float(H - e.y1), float(e.x1), float(H - e.y0)))
    return path, boxes


def _result(name: str, fig: Figure, out: Path, caption: str, colours: Mapping[str, str]
            ) -> FigureResult:
    path, boxes = _save(fig, out / f"{name}.png")
    return FigureResult(name, path, caption, dict(colours), boxes)


# ----------------------------------------------------------------- context
@dataclass
class _Context:
    """Everything the figure functions share for one study."""

    model: Any
    subject: str
    ed: int
    es: int
    axis: tuple[np.ndarray, np.ndarray]
    view: View
    oblique: View
    metrics: Mapping | None
    truth: Mapping | None
    tags: Any                          # TagMetrics or None
    tag_frames: dict[int, list[dict]]  # frame -> tag_figure_data
    tag_note: str | None               # why tags are unavailable
    bullseye: BullseyeCanvas | None = None   # the one bull's-eye figure of the study

    def surfaces(self, frame: int) -> dict:
        return dict(self.model.surfaces[frame])

    def frame_label(self, f: int) -> str:
        tag = " (ED)" if f == self.ed else " (ES)" if f == self.es else ""
        return f"frame {f}{tag}"


def _centroid(surface) -> np.ndarray:
    v, _ = nurbs.tessellate(surface, 12, 6)
    return np.asarray(v).mean(axis=0)


OBLIQUE_DEG = 35.0     # tag figures: the eye raised this much toward the base


def _make_view(model, frames: Sequence[int], axis, raise_deg: float = 0.0) -> View:
    """Camera of the model's panels (see module doc); ``raise_deg`` lifts the eye from
    the plane perpendicular to the long axis toward the base (tag planes seen obliquely)."""
    surf = model.surfaces[model.ed_frame]
    side = None
    if "rv_endo" in surf and "lv_endo" in surf:
        side = _centroid(surf["rv_endo"]) - _centroid(surf["lv_endo"])
    w, up = view_frame(axis, side)
    if raise_deg:
        r = math.radians(raise_deg)
        w, up = math.cos(r) * w + math.sin(r) * up, -math.sin(r) * w + math.cos(r) * up
    pts = []
    for f in frames:
        for s in model.surfaces[f].values():
            pts.append(np.asarray(s.control_points)[..., :3].reshape(-1, 3))
    centre, half = _bounds(pts)
    return _camera(w, up, centre, half)


def tag_data(model, tags: Any = None, frames: Sequence[int] | None = None,
             grid: tuple[int, int] = TAG_GRID) -> tuple[Any, dict[int, list[dict]], str | None]:
    """(TagMetrics, {frame: tag_figure_data}, note): tag surfaces of the model's study.

    ``tags`` (a TagMetrics from :func:`cardionurbs.analysis.tags.tag_metrics`) lends its
    QC flags; without it — or when the study has tags at three or more frames and
    ``tags`` lacks ``over_time`` (needed for the twist–time curve) — the metrics are
    computed here. ``note`` says why there
    are no tag surfaces (no tag lines, or the analysis failed), else None.

    Parameters
    ----------
    model : cardionurbs.anatomy.model.BiventricularModel
        The reconstructed model.
    tags : cardionurbs.analysis.tags.TagMetrics or None, optional
        The tag metrics of the analysis (QC flags, tag surfaces, over-time values).
    frames : sequence of int, optional
        The frames wanted (0-based; default every tagged frame).
    grid : tuple of (int, int), optional
        Samples (nu, nv) of each tag surface's tessellation.

    Returns
    -------
    tags : cardionurbs.analysis.tags.TagMetrics or None
        The tag metrics used.
    data : dict of int to list of dict
        Frame -> one :func:`cardionurbs.analysis.tags.tag_figure_data` dict per tag surface
        (vertices in mm, faces, family, index, lines, flags).
    note : str or None
        Why there are no tag surfaces, None when there are.
    """
    study = model.study
    if not getattr(study, "tags", None):
        return None, {}, "no tag lines in the study"
    from cardionurbs.analysis.tags import tag_figure_data, tag_metrics
    from cardionurbs.errors import CardioNurbsError
    try:
        axis = model.long_axis()
        over = len(study.tagged_frames) >= 3            # a twist–time curve is possible
        stale = over and not getattr(tags, "over_time", None)
        if tags is None or not hasattr(tags, "flags") or stale:
            tags = tag_metrics(model, over_time=over)
        flags = list(tags.flags)
        frames = [f for f in (frames if frames is not None else study.tagged_frames)
                  if f in study.tagged_frames]
        # the analysis's own tag surfaces where no line was left out of them (same study,
        # frame and axis: the same surfaces), else built here with every line
        built = getattr(tags, "surfaces", None) or {}
        flagged_at = {fl.frame for fl in flags}
        data = {f: tag_figure_data(study, f, long_axis=axis, flags=flags, nu=grid[0], nv=grid[1],
                                   surfaces=None if f in flagged_at else built.get(f))
                for f in frames}
    except (CardioNurbsError, ValueError, np.linalg.LinAlgError) as exc:
        return tags, {}, f"tag surfaces not built: {' '.join(str(exc).split())}"
    return tags, data, None


# ----------------------------------------------------------------- figures
FigureFn = Callable[[_Context, Path], "FigureResult | str"]


def _wall_pair(ctx: _Context, out: Path, name: str, structures: Sequence[str], fig_no: str,
               what: str, alphas: Mapping[str, float] | None = None) -> FigureResult | str:
    """Two panels (ED, ES) of the given wall surfaces."""
    alphas = alphas or {}
    frames = [ctx.ed] if ctx.ed == ctx.es else [ctx.ed, ctx.es]
    missing = [s for s in structures if s not in ctx.surfaces(ctx.ed)]
    if missing:
        return f"no {', '.join(missing)} surface in the model (no contours for it)"
    caption = (f"Fig. {fig_no}. {what} of subject {ctx.subject}, "
               + " and ".join(ctx.frame_label(f) for f in frames)
               + ". Scanner (LPS) mm; arrows: A anterior, L left, H head.")
    if ctx.ed == ctx.es:
        caption += " Only one frame was reconstructed: ES panel left out."
    fig, axes = _new_figure(len(frames), caption)
    for ax, f in zip(axes, frames):
        surf = ctx.surfaces(f)
        meshes = [surface_mesh(surf[s], STRUCTURE_COLOURS[s], alphas.get(s, 1.0), s)
                  for s in structures if s in surf]
        draw_panel(ax, meshes, ctx.view, title=ctx.frame_label(f))
    _legend(fig, [(NAMES[s], STRUCTURE_COLOURS[s]) for s in structures])
    opaque = {s: seen_colour(s, alphas, structures) for s in structures
              if alphas.get(s, 1.0) >= 1.0}
    return _result(name, fig, out, caption, opaque)


COVER = {"lv_endo": "lv_epi", "rv_endo": "rv_epi"}     # the wall around each cavity surface


def seen_colour(structure: str, alphas: Mapping[str, float], present: Sequence[str]) -> str:
    """Colour an opaque surface shows in the PNG: its own, or — inside a translucent wall of
    opacity a — the blend a·wall + (1 − a)·own (both shaded alike, so still a scaled colour).

    Parameters
    ----------
    structure : str
        The surface (``"lv_endo"``, ``"rv_endo"`` ...).
    alphas : mapping of str to float
        Structure -> opacity of the translucent walls of the figure.
    present : sequence of str
        The structures drawn.

    Returns
    -------
    str
        The hex colour the surface shows.
    """
    own = _rgb(STRUCTURE_COLOURS[structure])
    cover = COVER.get(structure)
    a = alphas.get(cover, 1.0) if cover is not None and cover in present else 0.0
    if cover is None or not 0.0 < a < 1.0:
        return STRUCTURE_COLOURS[structure]
    return matplotlib.colors.to_hex(tuple(a * _rgb(STRUCTURE_COLOURS[cover]) + (1 - a) * own))


def fig03_lv_endo(ctx, out):
    """Paper Fig. 3: the LV endocardial surface at ED and ES.

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context (model, ED/ES frames, views, metrics, tags).
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out.
    """
    return _wall_pair(ctx, out, "fig03_lv_endo_ed_es", ["lv_endo"], "3",
                      "LV endocardial surface (lv_endo)")


def fig04_lv_endo_epi(ctx, out):
    """Paper Fig. 4: the LV endocardium (opaque) inside the translucent epicardium, ED
    and ES.

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context (model, ED/ES frames, views, metrics, tags).
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out.
    """
    return _wall_pair(ctx, out, "fig04_lv_endo_epi", ["lv_endo", "lv_epi"], "4",
                      "LV endocardium (lv_endo, opaque) inside the LV epicardium (lv_epi, "
                      "translucent)", {"lv_epi": 0.35})


def fig05_rv_endo(ctx, out):
    """Paper Fig. 5: the RV endocardial surface (free wall and septum) at ED and ES.

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context (model, ED/ES frames, views, metrics, tags).
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out.
    """
    return _wall_pair(ctx, out, "fig05_rv_endo_ed_es", ["rv_endo"], "5",
                      "RV endocardial surface (rv_endo, free wall and septum)")


def fig06_rv_lv(ctx, out):
    """Paper Fig. 6: the RV endo- and epicardium around the LV epicardium, ED and ES.

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context (model, ED/ES frames, views, metrics, tags).
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out.
    """
    return _wall_pair(ctx, out, "fig06_rv_with_lv", ["lv_epi", "rv_endo", "rv_epi"], "6",
                      "RV endocardium (rv_endo, opaque) and epicardium (rv_epi, translucent) "
                      "wrapped around the LV epicardium (lv_epi)", {"rv_epi": 0.3})


def _tag_mesh(d: dict, colour: str, alpha: float = 1.0) -> Mesh:
    return Mesh(np.asarray(d["vertices"], float), np.asarray(d["faces"], np.int64), colour, alpha,
                f"{d['family']}#{d['index']}")


def _need_tags(ctx: _Context, frames: Sequence[int]) -> str | None:
    if ctx.tag_note:
        return ctx.tag_note
    absent = [f for f in frames if not ctx.tag_frames.get(f)]
    if absent:
        return f"no tag surfaces at frame(s) {absent} (tagged frames: {sorted(ctx.tag_frames)})"
    return None


def fig07_tag_surface(ctx, out):
    """One SA tag surface (middle index of family sa1) at ED and ES, with the long axis;
    the ES panel shows the ED surface as a grey outline: twist bends the plane about the
    axis and shortening moves its apical edge toward the base.

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context.
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out.
    """
    if ctx.ed == ctx.es:
        return "one frame only: ED and ES tag surfaces cannot be compared"
    why = _need_tags(ctx, [ctx.ed, ctx.es])
    if why:
        return why
    by = {f: {(d["family"], d["index"]): d for d in ctx.tag_frames[f]} for f in (ctx.ed, ctx.es)}
    common = sorted(set(by[ctx.ed]) & set(by[ctx.es]))
    fam = next((fm for fm in ("sa1", "sa2", "la") if any(k[0] == fm for k in common)), None)
    if fam is None:
        return "no tag surface present at both ED and ES"
    idx = [k for k in common if k[0] == fam]
    key = idx[len(idx) // 2]
    twist = ""
    if ctx.tags is not None and np.isfinite(ctx.tags.columns.get("Twist (deg)", np.nan)):
        twist = (f" Measured twist {ctx.tags.columns['Twist (deg)']:.1f} deg, "
                 f"LS {ctx.tags.columns['LS (%)']:.1f} %.")
    caption = (f"Fig. 7. Tag surface {fam} #{key[1]} ({NAMES[fam]}) of subject {ctx.subject} at "
               f"{ctx.frame_label(ctx.ed)} and {ctx.frame_label(ctx.es)}; black line: LV long "
               f"axis (apex to mitral centre, ED); grey: the ED surface.{twist}")
    fig, axes = _new_figure(2, caption)
    apex, base = ctx.axis
    axis_line = (np.vstack([apex, base]), "black", 1.5)
    ed_d = by[ctx.ed][key]
    box = _bounds([by[ctx.ed][key]["vertices"], by[ctx.es][key]["vertices"], apex, base])
    v = View(ctx.oblique.elev, ctx.oblique.azim, ctx.oblique.roll, *box)
    for ax, f in zip(axes, (ctx.ed, ctx.es)):
        meshes = [_tag_mesh(by[f][key], FAMILY_COLOURS[fam])]
        if f == ctx.es:
            meshes.append(_tag_mesh(ed_d, "#999999", 0.3))
        draw_panel(ax, meshes, v, lines=[axis_line], title=ctx.frame_label(f))
    _legend(fig, [(f"{fam} #{key[1]}", FAMILY_COLOURS[fam])])
    return _result("fig07_tag_surface_ed_es", fig, out, caption, {fam: FAMILY_COLOURS[fam]})


def fig08_tag_qc(ctx, out):
    """Tag surfaces (translucent grey) and their tag lines at the frame with most QC
    flags (else ES): lines flagged as mistracked in vermillion, the others in blue.

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context.
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out.
    """
    why = _need_tags(ctx, [])
    if why:
        return why
    flags = list(getattr(ctx.tags, "flags", []) or [])
    count = {f: sum(1 for g in flags if g.frame == f) for f in ctx.tag_frames}
    frame = max(count, key=lambda f: (count[f], f == ctx.es)) if count else ctx.es
    data = ctx.tag_frames.get(frame)
    if not data:
        return f"no tag surfaces at frame {frame}"
    meshes, lines = [], []
    n_bad = 0
    for d in data:
        meshes.append(_tag_mesh(d, "#BBBBBB", 0.25))
        for ln in d["lines"]:
            bad = bool(ln["flagged"])
            n_bad += bad
            lines.append((np.asarray(ln["points"]), FLAG_COLOUR if bad else GOOD_LINE_COLOUR,
                          2.6 if bad else 1.1))
    lines.sort(key=lambda t: t[1] == FLAG_COLOUR)       # flagged lines drawn last
    where = ", ".join(f"{g.family} #{g.index} in {g.slice}" for g in flags if g.frame == frame)
    caption = (f"Fig. 8. Tag QC of subject {ctx.subject}, {ctx.frame_label(frame)}: tag surfaces "
               f"(grey), tracked tag lines (blue) and {n_bad} line(s) flagged as mistracked "
               f"(vermillion){': ' + where if where else ''}.")
    fig, axes = _new_figure(1, caption, width=6.4, height=5.6)
    draw_panel(axes[0], meshes, ctx.oblique, lines=lines, title=ctx.frame_label(frame))
    items = [("tag line", GOOD_LINE_COLOUR)] + ([("flagged line", FLAG_COLOUR)] if n_bad else [])
    _legend(fig, items)
    colours = {"tag line": GOOD_LINE_COLOUR}
    if n_bad:
        colours["flagged line"] = FLAG_COLOUR
    return _result("fig08_tag_qc", fig, out, caption, colours)


def fig09_all_tag_surfaces(ctx, out):
    """Paper Fig. 9: every LV tag surface at ED (LA discs translucent).

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context (model, ED/ES frames, views, metrics, tags).
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out.
    """
    why = _need_tags(ctx, [ctx.ed])
    if why:
        return why
    data = ctx.tag_frames[ctx.ed]
    fams = sorted({d["family"] for d in data}, key=["sa1", "sa2", "la"].index)
    caption = (f"Fig. 9. All LV tag surfaces of subject {ctx.subject} at {ctx.frame_label(ctx.ed)}: "
               + ", ".join(f"{NAMES[f]} ({sum(d['family'] == f for d in data)})" for f in fams)
               + ". Scanner (LPS) mm.")
    fig, axes = _new_figure(1, caption, width=6.4, height=5.6)
    alpha = {"sa1": 1.0, "sa2": 1.0, "la": 0.45}        # LA discs translucent: SA planes show
    draw_panel(axes[0], [_tag_mesh(d, FAMILY_COLOURS[d["family"]], alpha[d["family"]])
                         for d in data], ctx.oblique, title=ctx.frame_label(ctx.ed))
    _legend(fig, [(f, FAMILY_COLOURS[f]) for f in fams])
    return _result("fig09_all_tag_surfaces", fig, out, caption,
                   {f: FAMILY_COLOURS[f] for f in fams if alpha[f] >= 1.0})


def fig10_biventricular(ctx, out):
    """Paper Fig. 10: the biventricular surfaces at ED with the tag planes.

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context (model, ED/ES frames, views, metrics, tags).
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out.
    """
    surf = ctx.surfaces(ctx.ed)
    if "rv_endo" not in surf:               # LV alone is figs 3-4: nothing biventricular to show
        return "no rv_endo surface in the model: the biventricular figure needs the RV"
    order = [s for s in ("lv_endo", "rv_endo", "lv_epi", "rv_epi") if s in surf]
    alpha = {"lv_endo": 1.0, "rv_endo": 1.0, "lv_epi": 0.3, "rv_epi": 0.3}
    meshes = [surface_mesh(surf[s], STRUCTURE_COLOURS[s], alpha[s], s) for s in order]
    tag_note = ""
    data = ctx.tag_frames.get(ctx.ed) or []
    if data:
        meshes += [_tag_mesh(d, FAMILY_COLOURS["la"], 0.55) for d in data if d["family"] == "la"]
        tag_note = " LA tag planes (yellow, translucent)."
    else:
        tag_note = f" No tag planes drawn: {ctx.tag_note or 'no tag surfaces at ED'}."
    caption = (f"Fig. 10. Biventricular model of subject {ctx.subject} at {ctx.frame_label(ctx.ed)}: "
               + ", ".join(f"{NAMES[s]} ({s})" for s in order) + "." + tag_note
               + " Scanner (LPS) mm.")
    fig, axes = _new_figure(1, caption, width=6.4, height=5.6)
    draw_panel(axes[0], meshes, ctx.oblique, title=ctx.frame_label(ctx.ed))
    items = [(NAMES[s], STRUCTURE_COLOURS[s]) for s in order]
    if data:
        items.append(("LA tag planes", FAMILY_COLOURS["la"]))
    _legend(fig, items)
    return _result("fig10_biventricular_tags", fig, out, caption, {s: seen_colour(s, alpha, order) for s in order if alpha[s] >= 1})


def _times(ctx: _Context, frames: Sequence[int]) -> tuple[np.ndarray, str]:
    t = ctx.model.study.frame_times_ms or {}
    if all(f in t for f in frames):
        return np.array([t[f] for f in frames], float), "time after R wave (ms)"
    return np.asarray(frames, float), "frame"


def fig11_volume_time(ctx, out):
    """LV and RV cavity volume (mL, closed manifold meshes) at every reconstructed frame.

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context.
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out (fewer than 3 frames).
    """
    frames = list(ctx.model.frames)
    if len(frames) < 3:
        return (f"{len(frames)} reconstructed frame(s) ({frames}): a volume–time curve needs "
                "at least 3")
    vols = {f: ctx.model.volumes[f] for f in frames}
    x, xlabel = _times(ctx, frames)
    keys = [k for k in ("lv_cavity", "rv_cavity") if all(k in vols[f] for f in frames)]
    colours = {"lv_cavity": STRUCTURE_COLOURS["lv_endo"], "rv_cavity": STRUCTURE_COLOURS["rv_endo"]}
    truth_v = ((ctx.truth or {}).get("volumes") or {}).get("analytic_mL") or {}
    has_truth = any(sum(str(f) in truth_v and isinstance(truth_v[str(f)].get(k), (int, float))
                        and np.isfinite(truth_v[str(f)][k]) for f in frames) >= 2 for k in keys)
    caption = (f"Volume–time curves of subject {ctx.subject}: LV and RV cavity volumes from the "
               f"closed meshes at {len(frames)} frames (ED frame {ctx.ed}, ES frame {ctx.es})"
               + ("; dashed: phantom truth." if has_truth else "."))
    fig, axes = _new_figure(1, caption, width=6.4, height=4.2, three_d=False)
    ax = axes[0]
    for k in keys:
        ax.plot(x, [vols[f][k] for f in frames], "-o", color=colours[k], ms=3, lw=1.8,
                label=k.replace("_", " "))
        tf = [f for f in frames if str(f) in truth_v and k in truth_v[str(f)]
              and truth_v[str(f)][k] is not None and np.isfinite(truth_v[str(f)][k])]
        if len(tf) >= 2:                # a truth curve (and its legend entry) only if drawn
            xt, _ = _times(ctx, tf)
            ax.plot(xt, [truth_v[str(f)][k] for f in tf], "--", color=colours[k], lw=1,
                    label=f"{k.replace('_', ' ')} (truth)")
    for f, lab in ((ctx.ed, "ED"), (ctx.es, "ES")):
        xf, _ = _times(ctx, [f])
        ax.axvline(xf[0], color="#777777", lw=0.8, ls=":")
        ax.text(xf[0], ax.get_ylim()[1], lab, fontsize=7, ha="center", va="bottom")
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_ylabel("volume (mL)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, frameon=False)
    return _result("fig11_volume_time", fig, out, caption, {k: colours[k] for k in keys})


def fig12_twist_time(ctx, out):
    """Twist (deg) and LS (%) relative to ED at every tagged frame (TagMetrics.over_time).

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context.
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out.
    """
    if ctx.tag_note and ctx.tags is None:
        return ctx.tag_note
    over = dict(getattr(ctx.tags, "over_time", {}) or {})
    frames = sorted(f for f, v in over.items() if np.isfinite(v.get("Twist (deg)", np.nan)))
    if len(frames) < 3:
        return (f"twist measured at {len(frames)} frame(s): a twist–time curve needs tags "
                "tracked at 3 or more frames")
    x, xlabel = _times(ctx, frames)
    caption = (f"Twist–time curve of subject {ctx.subject}: LV twist (apical minus basal rotation "
               f"of the LA tag levels, deg) and longitudinal shortening LS (%) relative to ED "
               f"(frame {ctx.ed}) at {len(frames)} tagged frames.")
    fig = Figure(figsize=(6.4, 5.0), dpi=DPI)
    ax, ax2 = fig.subplots(2, 1, sharex=True)
    fig.subplots_adjust(left=0.12, right=0.97, top=0.95, bottom=0.2, hspace=0.12)
    fig.text(0.01, 0.01, plain_text(textwrap.fill(caption, 110)), fontsize=7.5, ha="left",
             va="bottom")
    c1, c2 = OKABE_ITO["bluish_green"], OKABE_ITO["reddish_purple"]
    ax.plot(x, [over[f]["Twist (deg)"] for f in frames], "-o", color=c1, ms=3.5, lw=2.0,
            label="twist (measured)")
    ax2.plot(x, [over[f]["LS (%)"] for f in frames], "-s", color=c2, ms=3.5, lw=2.0,
             label="LS (measured)")
    tm = (ctx.truth or {}).get("metrics") or {}
    xe, _ = _times(ctx, [ctx.es])
    for a, key in ((ax, "Twist (deg)"), (ax2, "LS (%)")):
        if tm.get(key) is not None:
            a.plot([xe[0]], [tm[key]], marker="*", ms=10, color="black", ls="none",
                   label="truth at ES")
        a.axhline(0.0, color="#999999", lw=0.6)
        a.set_ylabel(key.replace(" (", "\n("), fontsize=8)
        a.tick_params(labelsize=7)
        a.legend(fontsize=7, frameon=False, loc="best")
    ax2.set_xlabel(xlabel, fontsize=8)
    return _result("fig12_twist_time", fig, out, caption, {"twist": c1, "LS": c2})


def fig18_labelmap_overlay(ctx, out):
    """Label-map studies with an image NIfTI beside them: the mid-ventricular SA image at
    ED and ES with the contours the label map gave drawn over it
    (:func:`cardionurbs.report.overlay.sa_overlay`).

    Parameters
    ----------
    ctx : _Context
        The study's shared figure context.
    out : pathlib.Path
        The folder the PNG goes to.

    Returns
    -------
    FigureResult or str
        The figure, or why it is left out (no image NIfTI, slice or frame not in it).
    """
    from cardionurbs.report.overlay import sa_overlay

    frames = sorted({ctx.ed, ctx.es})
    panels: list = []
    for f in frames:                  # the same slice at ES as at ED where it has contours
        res = sa_overlay(ctx.model.study, f, panels[0].slice) if panels else None
        if res is None or isinstance(res, str) or not res.contours.get("lv_endo"):
            res = sa_overlay(ctx.model.study, f)
        if isinstance(res, str):
            return res
        panels.append(res)
    palette = {**STRUCTURE_COLOURS, "rv_freewall": STRUCTURE_COLOURS["rv_endo"],
               "rv_septum": OKABE_ITO["bluish_green"]}
    order = ["lv_endo", "lv_epi", "rv_endo", "rv_freewall", "rv_septum", "rv_epi"]
    found = {k for p in panels for k in p.contours}
    colours = {k: palette.get(k, "#ffffff") for k in [*order, *sorted(found - set(order))]
               if k in found}
    caption = (f"Subject {ctx.subject}: the short-axis image beside the label map (slice "
               f"{', '.join(sorted({p.slice for p in panels}))}) with the contours taken from "
               "the labels, at "
               + " and ".join(ctx.frame_label(p.frame) for p in panels)
               + ". Contours mapped into the image through its own header: they should sit "
                 "on the blood-muscle edges.")
    fig, axes = _new_figure(len(panels), caption, width=4.2, height=4.4, three_d=False)
    for ax, p in zip(axes, panels):
        pts = np.concatenate([q for parts in p.contours.values() for q in parts])
        lo = np.maximum(np.floor(pts.min(axis=0)) - 15, 0).astype(int)
        hi = np.minimum(np.ceil(pts.max(axis=0)) + 15, p.image.shape).astype(int)
        ax.imshow(p.image[lo[0]:hi[0], lo[1]:hi[1]].T, cmap="gray", origin="upper",
                  extent=(lo[0] - 0.5, hi[0] - 0.5, hi[1] - 0.5, lo[1] - 0.5))
        for k, parts in p.contours.items():
            for q in parts:
                closed = k in ("lv_endo", "lv_epi", "rv_endo", "rv_epi")
                q = np.vstack([q, q[:1]]) if closed else q
                ax.plot(q[:, 0], q[:, 1], "-", color=colours[k], lw=1.2)
        ax.set_title(f"slice {p.slice}, {ctx.frame_label(p.frame)}", fontsize=8)
        ax.set_xlabel("pixel column", fontsize=7)
        ax.set_ylabel("pixel row", fontsize=7)
        ax.tick_params(labelsize=6)
    _legend(fig, [(k.replace("_", " "), c) for k, c in colours.items()])
    return _result("fig18_labelmap_overlay", fig, out, caption, colours)


FIGURES: dict[str, FigureFn] = {
    "fig03_lv_endo_ed_es": fig03_lv_endo, "fig04_lv_endo_epi": fig04_lv_endo_epi,
    "fig05_rv_endo_ed_es": fig05_rv_endo, "fig06_rv_with_lv": fig06_rv_lv,
    "fig07_tag_surface_ed_es": fig07_tag_surface, "fig08_tag_qc": fig08_tag_qc,
    "fig09_all_tag_surfaces": fig09_all_tag_surfaces,
    "fig10_biventricular_tags": fig10_biventricular, "fig11_volume_time": fig11_volume_time,
    "fig12_twist_time": fig12_twist_time,
}
#: figures drawn only for label-map studies (format nifti)
LABEL_MAP_FIGURES: dict[str, FigureFn] = {"fig18_labelmap_overlay": fig18_labelmap_overlay}


def _regional_columns(ctx) -> Mapping:
    """The metrics with the regional columns: as given, else the model's regional analysis
    (kept on the model by the pipeline, else computed once here)."""
    m = dict(ctx.metrics or {})
    if any(isinstance(m.get(f"WT_AHA_{k} (mm)"), float) and np.isfinite(m[f"WT_AHA_{k} (mm)"])
           for k in range(1, 17)):
        return m
    reg = getattr(ctx.model, "regional", None)
    if reg is None:
        from cardionurbs.analysis.regional import regional_metrics
        reg = regional_metrics(ctx.model, ctx.tags)
        ctx.model.regional = reg
    return {**m, **dict(reg)}


def _bullseye(quantity: tuple) -> FigureFn:
    """Figure function of one AHA bull's-eye (:mod:`cardionurbs.report.bullseye`)."""
    def fig(ctx, out):
        if ctx.bullseye is None:
            ctx.bullseye = BullseyeCanvas()
        res = quantity_figure(_regional_columns(ctx), quantity, ctx.subject, out,
                              frames=f"ED frame {ctx.ed}, ES frame {ctx.es}", canvas=ctx.bullseye)
        return res if isinstance(res, str) else FigureResult(quantity[0], res[0], res[1], {}, [])
    return fig


FIGURES.update({q[0]: _bullseye(q) for q in BULLSEYE_QUANTITIES})


# ----------------------------------------------------------------- driver
def _load_truth(model, truth) -> Mapping | None:
    if truth is not None and not isinstance(truth, (str, Path)):
        return truth
    path = Path(truth) if truth is not None else None
    if path is None and getattr(model.study, "source", None):
        src = Path(model.study.source)
        cand = (src if src.is_dir() else src.parent) / "truth.json"
        path = cand if cand.is_file() else None
    if path is None or not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def render_figures(model: Any, out_dir: str | Path, metrics: Mapping | None = None,
                   truth: Mapping | str | Path | None = None, tags: Any = None,
                   only: Sequence[str] | None = None, tag_grid: tuple[int, int] = TAG_GRID,
                   *, jobs: int | None = 1, meanwhile: Callable[[], Any] | None = None
                   ) -> FigureSet:
    """Render the figures of one model into ``out_dir``; see :func:`write_figures`.

    Also writes ``figures.json`` (captions, skip reasons, study source), ``skipped.txt``
    and, when tags exist, ``report_tags.json`` for the HTML report (coarse tag surfaces
    per tagged frame with QC flags).

    ``jobs``: processes drawing the figures (:func:`cardionurbs.parallel.fork_map`, each
    figure -- the bull's-eyes together, on their one canvas -- drawn whole by one worker;
    1, the default: all in this process, None: the usable CPUs); the files are those one
    process draws. ``meanwhile``: work of the caller run in this process while the workers
    draw (before the figures when they are drawn here).

    Parameters
    ----------
    model : cardionurbs.anatomy.model.BiventricularModel
    out_dir : path-like (the folder of the PNGs and their index files; made)
    metrics : mapping, optional (the docs/metrics.md dict: captions, bull's-eyes, curves)
    truth : mapping, str or path-like, optional (phantom truth or its ``truth.json``)
    tags : cardionurbs.analysis.tags.TagMetrics, optional (computed here when needed)
    only : sequence of str, optional (names of the figures to draw; default all)
    tag_grid : tuple of (int, int), optional (samples (nu, nv) of each tag surface)
    jobs : int or None, optional (processes drawing; 1: this one, None: the usable CPUs)
    meanwhile : callable, optional (run in this process while the workers draw)

    Returns
    -------
    FigureSet
        The figures written, the reasons for those left out, the report's tag surfaces.
    """
    from cardionurbs.parallel import fork_map
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fs = FigureSet()
    registry = dict(FIGURES)
    if model.study.meta.get("format") == "nifti":
        registry.update(LABEL_MAP_FIGURES)
    names = list(registry) if only is None else [n for n in registry if n in set(only)]
    axis = model.long_axis()
    ed, es = int(model.ed_frame), int(model.es_frame)
    view = _make_view(model, sorted({ed, es}), axis)
    oblique = _make_view(model, sorted({ed, es}), axis, OBLIQUE_DEG)
    tags_m, tag_frames, tag_note = tag_data(model, tags, grid=tag_grid)
    ctx = _Context(model, str(model.study.subject), ed, es, axis, view, oblique, metrics,
                   _load_truth(model, truth), tags_m, tag_frames, tag_note)

    def draw(group: tuple[str, ...]) -> dict[str, FigureResult | str]:
        drawn = {}
        for name in group:
            try:
                drawn[name] = registry[name](ctx, out)
            except (ValueError, KeyError, np.linalg.LinAlgError) as exc:   # never crash analyze
                drawn[name] = f"not drawn: {type(exc).__name__}: {' '.join(str(exc).split())}"
        return drawn

    bullseyes = tuple(n for n in names if n in {q[0] for q in BULLSEYE_QUANTITIES})
    groups: list[tuple[str, ...] | None] = [(n,) for n in names if n not in bullseyes]
    groups += [bullseyes] if bullseyes else []
    here: set | tuple = ()
    if meanwhile is not None:
        groups, here = [None, *groups], {None}
    drawn: dict = {}

    def work(g):
        if g is None:                          # the caller's own work, in this process
            assert meanwhile is not None
            return meanwhile()
        return draw(g)
    for g, res in zip(groups, fork_map(work, groups, jobs=jobs, here=here)):
        if g is not None:
            drawn.update(res)
    for name in names:
        res = drawn[name]
        if isinstance(res, FigureResult):
            fs.figures.append(res)
        else:
            fs.skipped[name] = str(res).splitlines()[0] if res else "not drawn"
    index = {"subject": ctx.subject, "source": getattr(model.study, "source", None),
             "ed_frame": ed, "es_frame": es,
             "figures": [{"name": f.name, "file": f.path.name, "caption": f.caption}
                         for f in fs.figures],
             "skipped": fs.skipped}
    atomic.write_text(out / "figures.json", json.dumps(index, indent=1))
    atomic.write_text(out / "skipped.txt",
                      "".join(f"{k}: {v}\n" for k, v in fs.skipped.items()))
    if tag_frames:
        with acyclic():                                 # plain lists (cardionurbs.heap)
            fs.report_tags = _tags_json(tag_frames, tags_m)
            atomic.write_text(out / "report_tags.json", _dump_tags(fs.report_tags))
    return fs


def _tags_json(tag_frames: Mapping[int, list[dict]], tags: Any) -> dict:
    """Coarse tag surfaces per frame (vertices rounded to 0.1 mm) with QC flags: the content
    of ``report_tags.json``, its arrays as numpy arrays (written by :func:`_dump_tags`)."""
    flags = [{"family": str(g.family), "index": int(g.index), "slice": str(g.slice),
              "frame": int(g.frame),
              "departure_spacings": (round(float(g.departure), 3) if np.isfinite(g.departure)
                                     else None), "reason": getattr(g, "reason", "jump")}
             for g in (getattr(tags, "flags", None) or [])]
    return {"frames": {str(f): [{"family": d["family"], "index": int(d["index"]),
                                 "flagged": bool(d["flagged"]),
                                 "flagged_slices": list(d["flagged_slices"]),
                                 "vertices": np.round(np.asarray(d["vertices"], float), 1),
                                 "faces": np.asarray(d["faces"]).astype(int),
                                 "flagged_lines": [np.round(np.asarray(ln["points"], float), 1)
                                                   for ln in d["lines"] if ln["flagged"]]}
                                for d in data] for f, data in tag_frames.items()},
            "flags": flags}


def _dump_tags(report_tags: Mapping) -> str:
    """JSON text of :func:`_tags_json`: each array becomes nested lists only while it is
    encoded (one surface's lists in memory at a time, not the whole study's)."""
    return json.dumps(report_tags, default=lambda a: a.tolist())


def write_figures(model: Any, out_dir: str | Path, metrics: Mapping | None = None,
                  truth: Mapping | str | Path | None = None, tags: Any = None) -> list[Path]:
    """Write the paper's figures of one reconstructed model as PNG files; return their paths.

    Parameters
    ----------
    model : BiventricularModel (``cardionurbs.reconstruct``)
    out_dir : folder for the PNGs (created), plus ``figures.json`` (captions and the
        reasons figures were left out), ``skipped.txt`` (one line per figure left
        out) and ``report_tags.json`` (tag surfaces for the HTML report).
    metrics : docs/metrics.md dict (optional; captions).
    truth : phantom truth dict or path to truth.json; default: ``truth.json`` beside
        the study source when present.
    tags : TagMetrics from ``cardionurbs.analysis.tags.tag_metrics`` (QC flags,
        twist over time); computed here when the study has tag lines.

    Figures: fig03 LV endo ED/ES (paper Fig. 3), fig04 LV endo+epi (Fig. 4), fig05/06 RV
    (Figs. 5-6), fig07 one tag surface ED/ES (Fig. 7), fig08 tag QC (Fig. 8), fig09 all
    tag surfaces (Fig. 9), fig10 biventricular + tag planes (Fig. 10), fig11
    volume–time, fig12 twist–time; label-map studies also fig13, the SA image NIfTI beside
    the labels with their contours over it (when the image is there).

    Returns
    -------
    list of pathlib.Path
        The PNG files written.
    """
    return render_figures(model, out_dir, metrics=metrics, truth=truth, tags=tags).paths
