"""Sunnybrook Cardiac Data: expert contour ``.txt`` files beside a DICOM cine series.

Layout (as in ../shared/data/sunnybrook and the published data set)::

    SC-HF-I-1/
      dicom/                               the cine series (any file names)
      i-contours/IM-0001-0048-icontour-manual.txt
      o-contours/IM-0001-0059-ocontour-manual.txt

Contour files may also lie directly in the study folder or any sub-folder.
File names are ``IM-SSSS-NNNN-<kind>contour-<manual|auto>.txt`` where
``NNNN`` is the InstanceNumber of the image the contour was drawn on and
``<kind>`` is ``i`` (LV endocardium -> ``lv_endo``), ``o`` (LV epicardium ->
``lv_epi``) or ``p1``/``p2`` (papillary muscles: not modelled, skipped and
listed in ``Study.meta["skipped_files"]``; ``Study.meta["contour_files"]`` names
the file of each contour, for messages). Each line holds one ``x y`` pixel
pair: x is the column index, y the row index, (0, 0) the centre of the first
pixel (the DICOM convention of :mod:`cardionurbs.imaging.geometry`); the loop
is closed (its first point is not repeated).

Labels: ED is the frame that carries epicardial (o-) contours, ES the other
frame with endocardial (i-) contours, as in the Sunnybrook protocol.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from cardionurbs.confine import checked, files_inside
from cardionurbs.errors import StudyError
from cardionurbs.imaging.dicom import read_dicom_folder
from cardionurbs.safe import excerpt
from cardionurbs.study import Contour, Study

CONTOUR_FILE = re.compile(r"^IM-(\d+)-(\d+)-([a-z0-9]+)contour-(manual|auto)\.txt$", re.IGNORECASE)
LOOSE_CONTOUR_FILE = re.compile(r"contour.*\.txt$", re.IGNORECASE)
STRUCTURE_OF_KIND = {"i": "lv_endo", "o": "lv_epi"}
SKIPPED_KINDS = ("p1", "p2")


def contour_files(folder: str | Path) -> list[Path]:
    """Every ``*contour*.txt`` file under ``folder`` (recursive, sorted).

    Parameters
    ----------
    folder : str or pathlib.Path
        A Sunnybrook study folder.

    Returns
    -------
    list of pathlib.Path
    """
    folder = Path(folder)
    return sorted(p for p in folder.rglob("*.txt") if LOOSE_CONTOUR_FILE.search(p.name)
                  and not any(part.startswith(".") for part in p.relative_to(folder).parts))


def _confined_contour_files(folder: Path) -> list[Path]:
    """:func:`contour_files`, each checked to resolve inside ``folder``
    (:func:`cardionurbs.confine.files_inside`)."""
    return files_inside(folder, contour_files(folder), what="contour file")


def detect(path: str | Path) -> bool:
    """True when ``path`` is a folder holding Sunnybrook contour files and DICOM images.

    Parameters
    ----------
    path : str or pathlib.Path
        A file or folder.

    Returns
    -------
    bool
    """
    p = Path(path)
    if not p.is_dir():
        return False
    has_contours = any(CONTOUR_FILE.match(q.name) for q in contour_files(p))
    if not has_contours:
        return False
    return (p / "dicom").is_dir() or any(q.suffix.lower() == ".dcm" for q in p.rglob("*.dcm"))


def read_contour_file(path: str | Path) -> np.ndarray:
    """(n, 2) pixel coordinates (column x, row y) of one contour file.

    Raises StudyError naming the file and line for an empty file, a line that
    is not two numbers, or a NaN / infinite value.

    Parameters
    ----------
    path : str or pathlib.Path
        A ``*contour-manual.txt`` file.

    Returns
    -------
    (n, 2) ndarray of float
        Pixel coordinates (x, y).

    Raises
    ------
    StudyError
        As above.
    """
    path = checked(path, what="contour file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise StudyError("not a text file (cannot decode as UTF-8)", file=path) from None
    lines = [(k + 1, ln.split()) for k, ln in enumerate(text.splitlines()) if ln.strip()]
    if not lines:
        raise StudyError("empty contour file (expected one 'x y' pixel pair per line)", file=path)
    bad = next(((k, tok) for k, tok in lines if len(tok) != 2), None)
    if bad:
        raise StudyError(f"line {bad[0]}: expected two numbers 'x y', got "
                         f"{excerpt(' '.join(bad[1]))}",
                         file=path)
    try:
        pts = np.array([[float(a), float(b)] for _, (a, b) in lines])
    except ValueError:
        for k, (a, b) in lines:
            try:
                float(a), float(b)
            except ValueError:
                raise StudyError(f"line {k}: not a number in {excerpt(a + ' ' + b)}",
                                 file=path) from None
        raise
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():
        k = lines[int(np.flatnonzero(~finite)[0])][0]
        raise StudyError(f"line {k}: NaN or infinite coordinate", file=path)
    return pts


def check_pixels_in_image(pix: np.ndarray, image, path: Path) -> None:
    """Every (x, y) pixel of a contour lies within its image, give or take
    :data:`cardionurbs.limits.CONTOUR_PIXEL_MARGIN` pixels; StudyError names the file, the
    line and the image size otherwise (a short number, never a 300-digit echo).

    Parameters
    ----------
    pix : (n, 2) ndarray of float
        The contour's pixel coordinates (x, y).
    image : ImagePlane
        Its image (``columns``, ``rows``).
    path : pathlib.Path
        The contour file, for the message.

    Raises
    ------
    StudyError
        A point outside the image.
    """
    from cardionurbs.limits import CONTOUR_PIXEL_MARGIN as m
    cols, rows = getattr(image, "columns", None), getattr(image, "rows", None)
    if not cols or not rows:
        return
    out = ((pix[:, 0] < -m) | (pix[:, 0] > cols - 1 + m)
           | (pix[:, 1] < -m) | (pix[:, 1] > rows - 1 + m))
    if out.any():
        k = int(np.flatnonzero(out)[0])
        raise StudyError(f"point {k + 1} ({pix[k, 0]:.4g}, {pix[k, 1]:.4g}) lies outside the "
                         f"{cols} x {rows} image (margin {m} pixels)", file=path)


def read_study(path: str | Path) -> Study:
    """Read a Sunnybrook study folder into a :class:`Study` (scanner mm).

    Each contour's pixel pairs are mapped through the plane of the image with
    the InstanceNumber in its file name (DICOM PS3.3 C.7.6.2.1.1), so every
    point lies exactly on that image plane.

    Parameters
    ----------
    path : str or pathlib.Path
        The study folder (contour folders beside DICOM images).

    Returns
    -------
    Study
        Contours, images and frame times; scanner mm, ms.

    Raises
    ------
    StudyError
        A missing or unreadable file, a contour outside its image, an image without geometry.
    """
    folder = Path(path)
    if not folder.is_dir():
        raise StudyError("a Sunnybrook study must be a folder", file=folder)
    files = _confined_contour_files(folder)
    if not files:
        raise StudyError("no *contour*.txt files in this folder", file=folder)
    dicom_root = folder / "dicom" if (folder / "dicom").is_dir() else folder
    series = read_dicom_folder(dicom_root, exclude=sorted({f.parent for f in files} - {folder}),
                               relative_to=folder)
    by_instance = series.by_instance_number()
    contours: list[Contour] = []
    sources: list[str] = []
    skipped: list[str] = []
    for f in files:
        m = CONTOUR_FILE.match(f.name)
        if not m:
            raise StudyError("contour file name must look like IM-0001-NNNN-icontour-manual.txt "
                             "(NNNN = InstanceNumber)", file=f)
        kind = m.group(3).lower()
        if kind in SKIPPED_KINDS:
            skipped.append(f.relative_to(folder).as_posix())
            continue
        if kind not in STRUCTURE_OF_KIND:
            raise StudyError(f"unknown contour kind {excerpt(kind + 'contour')}; expected icontour "
                             "(lv_endo), ocontour (lv_epi), p1contour or p2contour", file=f)
        inst = int(m.group(2))
        image = by_instance.get(inst)
        if image is None:
            raise StudyError(f"reference to image InstanceNumber {inst}, which is not in "
                             f"{dicom_root}", file=f, field="InstanceNumber")
        pix = read_contour_file(f)
        check_pixels_in_image(pix, image, f)
        try:
            contours.append(Contour(STRUCTURE_OF_KIND[kind], image.view, image.slice, image.frame,
                                    image.pixel_to_scanner(pix), image=image.id, closed=True))
        except StudyError as exc:
            raise StudyError(str(exc), file=f) from None
        sources.append(f.relative_to(folder).as_posix())
    _index_pieces(contours)
    ed, es = _ed_es_labels(contours)
    study = Study(subject=folder.name, images=list(series.images), contours=contours,
                  frame_times_ms=dict(series.frame_times_ms), heart_rate_bpm=series.heart_rate_bpm,
                  ed_frame=ed, es_frame=es, source=str(folder),
                  meta={"format": "sunnybrook", "dicom": dicom_root.relative_to(folder).as_posix()
                        if dicom_root != folder else ".",
                        "slice_spacing_mm": series.slice_spacing_mm,
                        "base_apex_rule": series.base_apex_rule,
                        "skipped_files": skipped, "contour_files": sources})
    return study


def _index_pieces(contours: list[Contour]) -> None:
    """Number several contours of one structure on one image 0, 1, ... (Contour.index)."""
    seen: dict[tuple, int] = {}
    for c in contours:
        key = (c.structure, c.image)
        c.index = seen.get(key, 0)
        seen[key] = c.index + 1


def _ed_es_labels(contours: list[Contour]) -> tuple[int | None, int | None]:
    """ED = the frame with most epicardial contours; ES = the other endocardial frame."""
    epi = [c.frame for c in contours if c.structure == "lv_epi"]
    endo = sorted({c.frame for c in contours if c.structure == "lv_endo"})
    if not epi:
        return None, None
    frames, counts = np.unique(epi, return_counts=True)
    ed = int(frames[np.argmax(counts)])
    others = [f for f in endo if f != ed]
    return ed, (others[0] if len(others) == 1 else None)
