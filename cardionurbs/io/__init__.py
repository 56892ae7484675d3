"""Study file formats (native, Sunnybrook, CAP GPFile) and model/mesh export."""

from __future__ import annotations

from pathlib import Path

from cardionurbs.errors import StudyError
from cardionurbs.study import Study

FORMATS = ("auto", "native", "sunnybrook", "gpfile", "phantom")


def detect_format(path: str | Path) -> str:
    """Tell the study format of ``path`` (a folder or a file in it)."""
    from cardionurbs.io import native

    p = Path(path)
    if not p.exists():
        raise StudyError("no such file or folder", file=p)
    if native.is_native(p):
        return "native"
    for reader in _extra_detectors():
        fmt = reader(p)
        if fmt:
            return fmt
    raise StudyError("cannot tell the study format (expected a native study.json, Sunnybrook "
                     "contour folders beside DICOM, or GPFile_*.txt + SliceInfoFile.txt)", file=p)


def _extra_detectors():
    """Detectors of the other formats; each returns a format name or None."""
    out = []
    try:
        from cardionurbs.io.sunnybrook import detect as sb
        out.append(lambda p: "sunnybrook" if sb(p) else None)
    except ImportError:
        pass
    try:
        from cardionurbs.io.gpfile import detect as gp
        out.append(lambda p: "gpfile" if gp(p) else None)
    except ImportError:
        pass
    return out


def load_study(path: str | Path, format: str = "auto") -> Study:
    """Read a study from ``path`` in ``format`` (``auto`` tells it from the files).

    ``phantom`` is a native study written by ``cardionurbs phantom`` (it reads
    the same way; ``truth.json`` beside it is not part of the Study).
    """
    if format not in FORMATS:
        raise StudyError(f"unknown format {format!r}; expected one of {', '.join(FORMATS)}",
                         field="format")
    fmt = detect_format(path) if format == "auto" else format
    if fmt in ("native", "phantom"):
        from cardionurbs.io.native import read_study
        return read_study(path)
    if fmt == "sunnybrook":
        from cardionurbs.io.sunnybrook import read_study
        return read_study(path)
    if fmt == "gpfile":
        from cardionurbs.io.gpfile import read_study
        return read_study(path)
    raise StudyError(f"format {fmt!r} is not readable", file=path)
