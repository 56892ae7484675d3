"""Inputs stay inside the study: every file a study names resolves inside its folder.

A study folder is read as a closed world: ``study.json``'s ``points`` and
image ``file`` entries, SliceInfoFile's file names, Sunnybrook contour files
and DICOM files found by walking the folder must all resolve inside the
study folder -- no absolute paths, no ``..`` components, no symbolic links
leading out. A study that needs files elsewhere is read with
``load_study(..., allow_outside=True)`` (CLI ``--allow-outside``), which sets
:func:`allow_outside` for the duration of the read.

The check is by *resolved* path, against the *resolved study root*:
:func:`cardionurbs.io.load_study` sets the root (:func:`study_root`) for the
whole read, and every reader passes each file through :func:`checked` right
before opening it (study.json, points files, DICOM files, contour files,
GPFiles, NIfTI maps and their sidecars). A subfolder of the study that is a
link elsewhere (a Sunnybrook ``dicom/``), a single file linked out (an ACDC
``_gt`` map) or a ``study.json`` that is itself a link are refused alike,
whatever folder the reader walked.

Messages name the offending entry through a short printable excerpt
(:func:`cardionurbs.safe.excerpt`), never the content of the file it points to.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Iterable, Iterator

from cardionurbs.errors import StudyError
from cardionurbs.safe import excerpt

_ALLOW_OUTSIDE: ContextVar[bool] = ContextVar("cardionurbs_allow_outside", default=False)
_ROOT: ContextVar[Path | None] = ContextVar("cardionurbs_study_root", default=None)

HINT = "(files must lie inside the study folder; --allow-outside lifts this)"


@contextmanager
def allow_outside(flag: bool = True) -> Iterator[None]:
    """Within this block, studies may name files outside their folder (when ``flag``).

    Parameters
    ----------
    flag : bool, optional
        ``True`` (default): lift the check for the block; ``False``: keep it (so that a
        caller can pass its ``allow_outside`` argument through unchanged).

    Yields
    ------
    None
        Control to the ``with`` block.
    """
    token = _ALLOW_OUTSIDE.set(bool(flag))
    try:
        yield
    finally:
        _ALLOW_OUTSIDE.reset(token)


def outside_allowed() -> bool:
    """True inside :func:`allow_outside`.

    Returns
    -------
    bool
        Whether the enclosing :func:`allow_outside` block lifted the check.
    """
    return _ALLOW_OUTSIDE.get()


@contextmanager
def study_root(path: str | os.PathLike) -> Iterator[Path]:
    """Within this block, every file read must resolve inside ``path`` (a study folder, or
    the folder of a single-file study), links followed once here. An enclosing root wins
    (a reader called from another reader keeps the outer study's root).

    Yields the resolved root.

    Parameters
    ----------
    path : path-like
        The study folder, or a single-file study (its parent folder is the root).

    Yields
    ------
    pathlib.Path
        The resolved root (the enclosing study's root when one is set already).
    """
    outer = _ROOT.get()
    if outer is not None:
        yield outer
        return
    p = Path(path)
    root = Path(os.path.realpath(p if p.is_dir() or not p.exists() else p.parent))
    token = _ROOT.set(root)
    try:
        yield root
    finally:
        _ROOT.reset(token)


def current_root() -> Path | None:
    """The resolved root set by :func:`study_root`, or None outside a study read.

    Returns
    -------
    pathlib.Path or None
        The resolved study root, or None when no study is being read.
    """
    return _ROOT.get()


def _root_for(folder: str | os.PathLike) -> Path:
    root = _ROOT.get()
    return root if root is not None else Path(os.path.realpath(folder))


def is_inside(folder: str | os.PathLike, path: str | os.PathLike) -> bool:
    """True when ``path``, every symbolic link followed, lies inside the current study root
    (:func:`study_root`) or, outside a study read, inside ``folder`` (also followed).

    Parameters
    ----------
    folder : path-like
        The bound outside a study read (resolved); inside one the study root is used.
    path : path-like
        The file or folder to test, links followed.

    Returns
    -------
    bool
        Whether the resolved ``path`` lies inside the bound.
    """
    return Path(os.path.realpath(path)).is_relative_to(_root_for(folder))


def checked(path: str | os.PathLike, *, what: str = "file") -> Path:
    """``path``, checked at open time to resolve (every link, of folders and of the file
    itself, followed now) inside the current study root; call it right before opening.

    Parameters
    ----------
    path : path-like
        The file (or folder) about to be read.
    what : str
        How the message names it (``"DICOM file"``, ``"study.json"``).

    Returns
    -------
    Path
        ``path`` unchanged. Outside a study read, or under :func:`allow_outside`, no check.

    Raises StudyError naming ``path`` (never its target) when it leads out."""
    root = _ROOT.get()
    if root is None or outside_allowed():
        return Path(path)
    if not Path(os.path.realpath(path)).is_relative_to(root):
        raise StudyError(f"{what} is (or lies under) a symbolic link leading out of the study "
                         f"folder {HINT}", file=path)
    return Path(path)


def study_file(folder: str | os.PathLike, name: object, *, file: object, field: str,
               slice: object = None, frame: object = None) -> Path:
    """``folder / name`` for a file name read from a study (``file``'s ``field``), checked to
    stay inside ``folder``: a non-empty relative path without ``..`` that, links followed,
    resolves inside. Raises StudyError quoting only an excerpt of ``name``.

    Parameters
    ----------
    folder : path-like
        The folder the name is relative to (the study folder or one of its subfolders).
    name : object
        The file name as read from the study file (must be non-empty text).
    file : path-like or str
        The study file that named it, for the message.
    field : str
        The field of ``file`` that held the name (``"points"``, ``"file"``).
    slice : object, optional
        The slice id the entry belongs to, for the message.
    frame : object, optional
        The frame index (0-based) the entry belongs to, for the message.

    Returns
    -------
    pathlib.Path
        ``folder / name`` (not resolved). Under :func:`allow_outside` only the text checks
        (non-empty, no NUL) are made.

    Raises
    ------
    cardionurbs.errors.StudyError
        ``name`` is not text, empty, holds a NUL, is absolute, has a ``..`` component or
        resolves (links followed) outside the study; the message quotes only an excerpt.
    """
    where = dict(file=file, field=field, slice=slice, frame=frame)
    if not isinstance(name, str) or not name.strip():
        raise StudyError(f"a file name must be non-empty text, got {excerpt(name)}", **where)
    if "\x00" in name:
        raise StudyError(f"file name {excerpt(name)} holds a NUL character", **where)
    p = Path(name)
    if outside_allowed():
        return Path(folder) / p
    if p.is_absolute() or name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":"):
        raise StudyError(f"file name {excerpt(name)} is an absolute path {HINT}", **where)
    if ".." in p.parts or ".." in name.replace("\\", "/").split("/"):
        raise StudyError(f"file name {excerpt(name)} leads out of the study folder with '..' "
                         f"{HINT}", **where)
    full = Path(folder) / p
    if not is_inside(folder, full):
        raise StudyError(f"file {excerpt(name)} is a symbolic link leading out of the study "
                         f"folder {HINT}", **where)
    return full


def files_inside(folder: str | os.PathLike, paths: Iterable[Path], *, what: str = "file"
                 ) -> list[Path]:
    """``paths`` (found by walking ``folder``), each checked to resolve inside ``folder``;
    a symbolic link leading out raises StudyError naming the link (not its target).
    Inside a study read the bound is the study root (:func:`study_root`), not ``folder``:
    a walked subfolder that is itself a link elsewhere does not widen it.

    Parameters
    ----------
    folder : path-like
        The walked folder (the bound outside a study read).
    paths : iterable of pathlib.Path
        The files found by walking it.
    what : str, optional
        How the message names a file (``"DICOM file"``).

    Returns
    -------
    list of pathlib.Path
        ``paths`` as a list, unchanged.

    Raises
    ------
    cardionurbs.errors.StudyError
        A path resolves outside the bound; the message names the link, not its target.
    """
    paths = list(paths)
    if outside_allowed():
        return paths
    root = _root_for(folder)
    for p in paths:
        if not Path(os.path.realpath(p)).is_relative_to(root):
            raise StudyError(f"{what} is (or lies under) a symbolic link leading out of the "
                             f"study folder {HINT}", file=p)
    return paths
