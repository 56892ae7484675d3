"""Study file formats (native, Sunnybrook, CAP GPFile, NIfTI label maps) and model/mesh export.

:func:`load_study` reads a study in any supported format and runs
:func:`cardionurbs.io.checks.check_study` on it: fatal problems raise
:class:`~cardionurbs.errors.StudyError` (one line naming file, slice and
frame); warnings are returned in ``study.warnings`` (one line each,
not printed, so that callers decide how to show them).
"""

from __future__ import annotations

import re
from pathlib import Path

from cardionurbs.errors import StudyError
from cardionurbs.io.checks import check_study
from cardionurbs.study import Study

FORMATS = ("auto", "native", "sunnybrook", "gpfile", "phantom", "nifti")
__all__ = ["FORMATS", "detect_format", "load_study", "check_study", "studies_in"]


def detect_format(path: str | Path) -> str:
    """Tell the study format of ``path`` (a folder or a file in it).

    ``native`` (a study.json manifest of format cardionurbs-native),
    ``gpfile`` (GPFile_NNN.txt + SliceInfoFile.txt), ``sunnybrook``
    (``*contour-manual.txt`` files beside DICOM images), ``nifti`` (a ``.nii``/``.nii.gz``
    label map, or a folder in the ACDC, UK Biobank or M&Ms layout).

    Parameters
    ----------
    path : str or pathlib.Path
        A study folder or a file in it.

    Returns
    -------
    str
        ``native``, ``gpfile``, ``sunnybrook`` or ``nifti``.

    Raises
    ------
    StudyError
        ``path`` does not exist, or no format's files are there (with a hint at what is).
    """
    p = Path(path)
    if not p.exists():
        raise StudyError("no such file or folder", file=p)
    fmt = _format_or_none(p)
    if fmt:
        return fmt
    hint = ""
    inner = [q.name for q in _subfolders(p) if _format_or_none(q)] if p.is_dir() else []
    if p.is_file():
        hint = " (expected a .nii/.nii.gz label map or a study folder)"
    elif inner:
        shown = ", ".join(inner[:3]) + (", ..." if len(inner) > 3 else "")
        hint = (f" (a folder of {len(inner)} studies: {shown}: analyze one of them, or measure "
                "them all with `cardionurbs cohort FOLDER --csv FILE`)")
    elif p.is_dir() and (p / "Info.cfg").is_file():
        other = sorted(q.name for q in p.iterdir() if q.name.lower().endswith((".nii", ".nii.gz"))
                       and not q.name.lower().endswith(("_4d.nii", "_4d.nii.gz"))
                       and not re.search(r"_frame\d+\.nii", q.name, re.I))
        hint = (" (an ACDC patient folder without its label maps, the *_frameMM_gt.nii.gz files"
                + (f"; to read another map give the file itself: {', '.join(other[:3])}" if other
                   else "") + ")")
    elif p.is_dir() and _has_dicom(p):
        hint = " (DICOM images but no contours beside them)"
    raise StudyError("cannot tell the study format (expected a native study.json, Sunnybrook "
                     "contour folders beside DICOM, GPFile_*.txt or one GPFile.txt + SliceInfoFile.txt, "
                     "or NIfTI label maps)" + hint,
                     file=p)


def _format_or_none(p: Path) -> str | None:
    from cardionurbs.io import native

    if native.is_native(p) or (p.is_dir() and (p / native.MANIFEST).is_file()):
        return "native"  # a broken study.json is reported by the native reader
    for reader in _extra_detectors():
        fmt = reader(p)
        if fmt:
            return fmt
    return None


def _subfolders(p: Path) -> list[Path]:
    """The folders directly in ``p`` (symbolic links not followed), by name."""
    return sorted(q for q in p.iterdir() if q.is_dir() and not q.is_symlink())


def studies_in(path: str | Path, depth: int = 3) -> list[Path]:
    """The studies at or below ``path``: ``[path]`` when it is a study, else the study
    folders up to ``depth`` levels below it (a dataset as distributed: ACDC
    ``database/training/patientNNN``, M&Ms ``OpenDataset/Training/Labeled/<code>``), by
    name, not looking inside a study; symbolic links are not followed.

    Parameters
    ----------
    path : str or pathlib.Path
        A study, or a folder of them.
    depth : int, optional
        How many folder levels below ``path`` to look.

    Returns
    -------
    list of pathlib.Path
        The studies found (empty when none).
    """
    p = Path(path)
    if not p.exists():
        return []
    if _format_or_none(p):
        return [p]
    if not p.is_dir() or depth <= 0:
        return []
    return [s for q in _subfolders(p) for s in studies_in(q, depth - 1)]


def _has_dicom(p: Path) -> bool:
    return any(q.suffix.lower() in (".dcm", ".ima") for q in p.rglob("*"))


def _extra_detectors():
    """Detectors of the other formats; each returns a format name or None. Each reader
    module is imported only when its detector is asked (the Sunnybrook reader brings
    pydicom, about 0.5 s of a start-up that reads a GPFile study)."""
    def nii(p):
        names = [p.name] if p.is_file() else [q.name for q in p.iterdir()] if p.is_dir() else []
        if not any(n.lower().endswith((".nii", ".nii.gz")) for n in names):
            return None                    # no label map here: the NIfTI reader is not needed
        from cardionurbs.io.nifti import detect
        return "nifti" if detect(p) else None

    def gp(p):
        from cardionurbs.io.gpfile import detect
        return "gpfile" if detect(p) else None

    def sb(p):
        from cardionurbs.io.sunnybrook import detect
        return "sunnybrook" if detect(p) else None

    return [nii, gp, sb]


def load_study(path: str | Path, format: str = "auto", *, allow_outside: bool = False,
               labels=None, ed_frame: int | None = None, es_frame: int | None = None) -> Study:
    """Read a study from ``path`` in ``format``, then check it
    (:func:`cardionurbs.io.checks.check_study`).

    ``phantom`` is a native study written by ``cardionurbs phantom`` (it reads
    the same way; ``truth.json`` beside it is not part of the Study). For a
    native study whose images name DICOM files that exist, the manifest's
    geometry is cross-checked against the DICOM headers.

    Parameters
    ----------
    path : str or pathlib.Path
        The study folder, or a file in it (a ``study.json`` manifest, a ``.nii``/``.nii.gz``
        label map).
    format : {"auto", "native", "sunnybrook", "gpfile", "phantom", "nifti"}
        The study format (docs/formats.md); ``auto`` tells it from the files
        (:func:`detect_format`).
    allow_outside : bool
        Let the study name files outside its folder (absolute paths, ``..`` or symbolic
        links leading out), refused by default (:mod:`cardionurbs.confine`).
    labels : str, dict or None
        NIfTI label maps only: a preset (``acdc``, ``ukbb``, ``mnms``, ``bivme``) or a
        ``lv=…,myo=…,rv=…`` mapping of roles to label values; None takes the layout's preset,
        or infers the roles from topology for a single file (:mod:`cardionurbs.io.labels`).
    ed_frame, es_frame : int or None
        NIfTI label maps only: the ED and ES frame indices (0-based); None reads them from
        the layout's files, else the model's rule chooses.

    Returns
    -------
    Study
        Geometry in scanner (patient LPS) mm, times in ms; ``study.warnings`` holds the
        checks' one-line warnings (not printed: callers decide how to show them).

    Raises
    ------
    StudyError
        Unreadable, unsafe or inconsistent input: one line naming the file, slice, frame and
        field.

    Examples
    --------
    A phantom study (known truth) written as a native study folder and read back:

    >>> import pathlib, tempfile
    >>> import cardionurbs as cn
    >>> from cardionurbs.phantom import generate, write_phantom
    >>> phantom = generate("normal", seed=1, frames=2, n_sa=6, matrix=128, volume_check=False)
    >>> tmp = tempfile.TemporaryDirectory()
    >>> folder = write_phantom(phantom, pathlib.Path(tmp.name) / "p1", dicom=False)
    >>> study = cn.load_study(folder)
    >>> study.subject, sorted(study.frames), study.ed_frame
    ('normal_001', [0, 1], 0)
    >>> sorted({c.structure for c in study.contours})[:3]
    ['lv_endo', 'lv_epi', 'rv_endo']
    >>> tmp.cleanup()
    """
    from cardionurbs.confine import allow_outside as _allow
    from cardionurbs.confine import study_root

    with _allow(allow_outside), study_root(path):
        return _load_study(path, format, labels=labels, ed_frame=ed_frame, es_frame=es_frame)


def _load_study(path: str | Path, format: str, *, labels=None, ed_frame: int | None = None,
                es_frame: int | None = None) -> Study:
    if format not in FORMATS:
        raise StudyError(f"unknown format {format!r}; expected one of {', '.join(FORMATS)}",
                         field="format")
    fmt = detect_format(path) if format == "auto" else format
    if not Path(path).exists():
        raise StudyError("no such file or folder", file=path)
    if fmt != "nifti" and (labels is not None or ed_frame is not None or es_frame is not None):
        raise StudyError(f"labels / ed_frame / es_frame apply to NIfTI label maps, not to the "
                         f"{fmt} format", file=path, field="labels")
    if fmt in ("native", "phantom"):
        from cardionurbs.io.native import check_dicom_geometry, read_study
        study = read_study(path)
        check_dicom_geometry(study)
    elif fmt == "sunnybrook":
        from cardionurbs.io.sunnybrook import read_study
        study = read_study(path)
    elif fmt == "gpfile":
        from cardionurbs.io.gpfile import read_study
        study = read_study(path)
    elif fmt == "nifti":
        from cardionurbs.io.nifti import read_study as read_nifti_study
        study = read_nifti_study(path, labels=labels, ed_frame=ed_frame, es_frame=es_frame)
    else:  # pragma: no cover - FORMATS and this list agree
        raise StudyError(f"format {fmt!r} is not readable", file=path)
    study.warnings = (list(study.meta.pop("reader_warnings", [])) + list(study.warnings or [])
                      + check_study(study))
    from cardionurbs.io.body import attach_body
    attach_body(study)                      # height, weight, age, sex: study.meta["body"]
    return study
