"""Regional function on the meshes: the point data of the ``.vtp`` files (docs/formats.md).

Per frame f and mesh (:meth:`BiventricularModel.mesh_arrays`):

* every mesh: ``time (ms)``, the frame's trigger time (the ``.pvd`` timestep too);
* ``lv_myocardium``: ``wall thickness (mm)`` and ``AHA segment`` — the thickness rays of
  :func:`cardionurbs.analysis.thickness.thickness_by_segment` at frame f (at ED and ES
  the very rays of the ``WT_AHA_*`` columns), each vertex taking the value and segment of
  the ray nearest to it (rays sampled at five points from endo- to epicardium, a k-d
  tree query); NaN (segment 0) farther than :data:`RAY_REACH_MM` from every ray (beyond
  the mitral plane, where no ray is cast);
* ``lv_cavity`` (the LV endocardium): ``AHA segment`` of each vertex
  (:meth:`cardionurbs.analysis.aha.AhaFrame.segments` at frame f; 0 above the mitral
  plane) and, when the study has tags, ``Err (%)``, ``Ecc (%)``, ``Ell (%)``: the
  Lagrangian strain ED → f of the vertex's segment (the ``*_AHA_k`` value at that frame,
  :mod:`cardionurbs.analysis.regional`; 0 at ED, NaN in segment 17, outside the
  segments and at frames the strain was not measured at).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from cardionurbs.analysis.aha import model_aha_frame
from cardionurbs.analysis.strain import STRAIN_KINDS
from cardionurbs.analysis.thickness import thickness_by_segment
from cardionurbs.errors import CardioNurbsError
from cardionurbs.io.vtkfiles import write_pvd, write_vtp

#: a myocardium vertex farther than this from every thickness ray gets no thickness (mm)
RAY_REACH_MM = 5.0
THICKNESS = "wall thickness (mm)"
SEGMENT = "AHA segment"
TIME = "time (ms)"


def frame_time_ms(model, frame: int) -> float:
    """The trigger time of ``frame`` (ms); the frame index where the study has no times.

    Parameters
    ----------
    model : BiventricularModel
        The model.
    frame : int
        A frame index.

    Returns
    -------
    float
        ms, or the index.
    """
    t = (model.study.frame_times_ms or {}).get(frame)
    return float(frame) if t is None else float(t)


def _regional_part(model, frame: int):
    """(AhaFrame, thickness samples) of ``frame``: those of ``model.regional`` (ED, ES)
    when the analysis made them, else computed here."""
    regional = getattr(model, "regional", None)
    if regional is not None and frame in regional.aha and frame in regional.samples:
        return regional.aha[frame], regional.samples[frame]
    surf = model.surfaces[frame]
    aha = model_aha_frame(model, frame)
    if "lv_endo" not in surf or "lv_epi" not in surf:
        return aha, None
    _, samples = thickness_by_segment(surf["lv_endo"], surf["lv_epi"], aha,
                                      model.base_planes[frame].get("lv"))
    return aha, samples


def wall_fields(samples: dict, vertices: np.ndarray) -> dict[str, np.ndarray]:
    """``wall thickness (mm)`` and ``AHA segment`` of each myocardium vertex from the
    thickness rays (module docstring).

    Parameters
    ----------
    samples : dict
        :func:`~cardionurbs.analysis.thickness.thickness_by_segment` samples: ``points``
        (n, 3) mm, ``normals`` (n, 3), ``thickness`` (n,) mm (NaN: ray missed),
        ``segment`` (n,).
    vertices : (V, 3) array
        Mesh vertices, mm.

    Returns
    -------
    dict
        name -> (V,) array: thickness in mm (NaN where no ray reaches), segment (int).
    """
    t = np.asarray(samples["thickness"], float)
    ok = np.isfinite(t)
    P, N, t, seg = samples["points"][ok], samples["normals"][ok], t[ok], samples["segment"][ok]
    V = np.asarray(vertices, float).reshape(-1, 3)
    if not len(t):
        return {THICKNESS: np.full(len(V), np.nan), SEGMENT: np.zeros(len(V), np.int32)}
    s = np.linspace(0.0, 1.0, 5)
    along = P[None, :, :] + (s[:, None, None] * t[None, :, None]) * N[None, :, :]
    dist, idx = cKDTree(along.reshape(-1, 3)).query(V)
    ray = idx % len(t)
    near = dist <= RAY_REACH_MM
    return {THICKNESS: np.where(near, t[ray], np.nan),
            SEGMENT: np.where(near, seg[ray], 0).astype(np.int32)}


def endocardium_fields(model, frame: int, aha, vertices: np.ndarray) -> dict[str, np.ndarray]:
    """``AHA segment`` of each LV endocardial vertex and, for a tagged study, the segment
    strains ED → ``frame`` (``Err (%)``, ``Ecc (%)``, ``Ell (%)``; module docstring).

    Parameters
    ----------
    model : BiventricularModel
        The model (with ``model.regional`` for the strains).
    frame : int
        The frame.
    aha : AhaFrame
        The frame's AHA segment frame (:mod:`cardionurbs.analysis.aha`).
    vertices : (V, 3) ndarray
        The LV endocardial mesh vertices, mm.

    Returns
    -------
    dict of str to (V,) ndarray
        Array name -> per-vertex values (the AHA segment; strains in %).
    """
    seg = aha.segments(np.asarray(vertices, float)).astype(np.int32)
    out: dict[str, np.ndarray] = {SEGMENT: seg}
    if not model.study.tags:
        return out
    regional = getattr(model, "regional", None)
    over = getattr(regional, "over_time", None) or {}
    cols = over.get(frame, {}).get("columns") if frame != model.ed_frame else None
    if cols is None and regional is not None and frame == model.es_frame and regional.strain:
        cols = regional.strain.get("columns")
    for kind in STRAIN_KINDS:
        table = np.full(18, np.nan)
        if frame == model.ed_frame:
            table[1:17] = 0.0                         # the reference configuration
        elif cols is not None:
            table[1:17] = [cols.get(f"{kind}_AHA_{k} (%)", np.nan) for k in range(1, 17)]
        out[f"{kind} (%)"] = table[np.clip(seg, 0, 17)]
    return out


def frame_point_data(model, frame: int, meshes: dict[str, tuple[np.ndarray, np.ndarray]]
                     ) -> dict[str, dict[str, np.ndarray]]:
    """Point data of every mesh of one frame (module docstring): mesh name -> {array
    name -> (V,) array}. AHA segments and thickness are left out (with a warning in
    ``model.warnings``) when the frame's segments cannot be placed.

    Parameters
    ----------
    model : BiventricularModel
        The model.
    frame : int
        The frame.
    meshes : dict of str to (vertices (V, 3), faces (F, 3))
        The frame's meshes (:meth:`~cardionurbs.anatomy.model.BiventricularModel.mesh_arrays`).

    Returns
    -------
    dict of str to dict of str to ndarray
    """
    t = frame_time_ms(model, frame)
    out = {name: {TIME: np.full(len(v), t)} for name, (v, _) in meshes.items()}
    if not {"lv_cavity", "lv_myocardium"} & set(meshes):
        return out
    try:
        aha, samples = _regional_part(model, frame)
    except CardioNurbsError as exc:
        model.warnings.append(f"frame {frame}: no wall thickness or AHA segments on the "
                              f"meshes: {exc}")
        return out
    if "lv_cavity" in meshes:
        out["lv_cavity"].update(endocardium_fields(model, frame, aha, meshes["lv_cavity"][0]))
    if "lv_myocardium" in meshes and samples is not None:
        out["lv_myocardium"].update(wall_fields(samples, meshes["lv_myocardium"][0]))
    return out


def vtp_name(frame: int, mesh: str) -> str:
    """The file name of one frame's mesh: ``frame_NN_<mesh>.vtp``.

    Parameters
    ----------
    frame : int
        The frame.
    mesh : str
        The mesh name (``lv_cavity`` ...).

    Returns
    -------
    str
    """
    return f"frame_{frame:02d}_{mesh}.vtp"


def write_frame_vtp(model, frame: int, mesh_dir: str | Path) -> list[Path]:
    """Write every mesh of ``frame`` as ``mesh_dir/frame_NN_<mesh>.vtp`` with its point
    data (:func:`frame_point_data`).

    Parameters
    ----------
    model : BiventricularModel
        The reconstructed model.
    frame : int
        The frame whose closed meshes (scanner mm) are written.
    mesh_dir : str or pathlib.Path
        The folder to write into (it must exist).

    Returns
    -------
    list of pathlib.Path
        The ``.vtp`` files written, one per mesh.
    """
    meshes = model.mesh_arrays(frame)
    data = frame_point_data(model, frame, meshes)
    t = frame_time_ms(model, frame)
    return [write_vtp(Path(mesh_dir) / vtp_name(frame, name), v, fc, data[name], time_ms=t)
            for name, (v, fc) in meshes.items()]


def write_pvd_series(model, mesh_dir: str | Path) -> list[Path]:
    """One ParaView collection per mesh, ``mesh_dir/<mesh>.pvd``, over the frames whose
    ``.vtp`` files are in ``mesh_dir``, at the frames' times (ms).

    Without frame times in the study the timesteps are frame indices, and a warning says so
    in ``model.warnings``.

    Parameters
    ----------
    model : BiventricularModel
        The model whose frames' ``.vtp`` files (:func:`write_frame_vtp`) are collected.
    mesh_dir : str or pathlib.Path
        The folder holding them.

    Returns
    -------
    list of pathlib.Path
        The ``.pvd`` files written, one per mesh, sorted by mesh name.
    """
    mesh_dir = Path(mesh_dir)
    names: dict[str, list[tuple[float, str]]] = {}
    for f in model.frames:
        for p in sorted(mesh_dir.glob(f"frame_{f:02d}_*.vtp")):
            mesh = p.stem[len(f"frame_{f:02d}_"):]
            names.setdefault(mesh, []).append((frame_time_ms(model, f), p.name))
    if not (model.study.frame_times_ms or {}):
        model.warnings.append("the study has no frame times: the .pvd timesteps are frame indices")
    return [write_pvd(mesh_dir / f"{mesh}.pvd", rows) for mesh, rows in sorted(names.items())]
