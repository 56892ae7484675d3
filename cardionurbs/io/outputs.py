"""Output paths that never destroy anything: checked before any work, replaced atomically.

Every command that writes a folder (``analyze``, ``phantom``, ``demo``) or a
file (``cohort --csv``, ``report --out``) calls :func:`check_output_dir` or
:func:`check_output_file` *before* it reads or computes anything:

* an output folder must be absent, an empty folder, or a folder this package
  wrote before (it holds the marker file :data:`MARKER`) and then only with
  ``overwrite=True`` (the CLI's ``--overwrite``) and only when it holds nothing but
  the files the marker's manifest lists: a file a user added (``notes.txt``) makes
  ``--overwrite`` refuse, naming it;
* inputs and outputs are told apart: a study cardionurbs generated (``phantom``)
  carries :data:`STUDY_MARKER` instead, which only ``phantom --overwrite`` accepts, so
  no output command can replace a study;
* an existing file where a folder is asked for, or a folder where a file is
  asked for, is refused; so is a symbolic link;
* the output may not be, contain, or lie inside any input (the study read),
  nor be or contain the current working folder;
* an output file may not be one of the input files or lie inside an input
  folder it would replace.

The folder itself is then written by :func:`cardionurbs.io.atomic.atomic_dir`
(a temporary sibling folder renamed onto the output when complete, the marker
written first), so an interrupted run (Ctrl-C, SIGTERM, ``kill -9``) leaves
the previous output intact; the temporary debris a killed run leaves is
removed by the next run (:func:`cardionurbs.io.atomic.remove_stale_temporaries`).
Violations raise :class:`~cardionurbs.errors.OutputError` (CLI exit 2).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

from cardionurbs.errors import OutputError
from cardionurbs.safe import excerpt
from cardionurbs.io.atomic import (MARKER, STUDY_MARKER, _tree_files, read_marker,
                                   remove_stale_temporaries)

__all__ = ["MARKER", "STUDY_MARKER", "check_output_dir", "check_output_file",
           "is_cardionurbs_output", "foreign_files"]


def is_cardionurbs_output(path: str | os.PathLike) -> bool:
    """True when ``path`` is a folder holding the marker this package writes into its outputs.

    Parameters
    ----------
    path : str or os.PathLike
        A path.

    Returns
    -------
    bool
    """
    p = Path(path)
    return p.is_dir() and (p / MARKER).is_file()


def foreign_files(folder: str | os.PathLike, manifest: dict) -> list[str]:
    """The entries under ``folder`` that ``manifest`` (a marker's, :func:`read_marker`) does
    not list: files and links outside its ``files`` and ``trees``, and empty folders
    that are not parents of a listed file. Sorted POSIX relative paths.

    Parameters
    ----------
    folder : str or os.PathLike
        An earlier output folder.
    manifest : dict
        Its marker's manifest (``files``, ``trees``).

    Returns
    -------
    list of str
        The entries the manifest does not account for.
    """
    folder = Path(folder)
    listed = {f for f in manifest.get("files", []) if isinstance(f, str)}
    trees = tuple(t.rstrip("/") + "/" for t in manifest.get("trees", []) if isinstance(t, str))
    extra = [f for f in _tree_files(folder)
             if f not in listed and Path(f).name not in (MARKER, STUDY_MARKER)
             and not f.startswith(trees)]
    parents = {p.as_posix() for f in listed for p in Path(f).parents}
    for dirpath, dirnames, filenames in os.walk(folder):
        rel = Path(dirpath).relative_to(folder).as_posix()
        if rel != "." and not dirnames and not filenames and rel not in parents \
                and not (rel + "/").startswith(trees):
            extra.append(rel + "/")
    return sorted(extra)


def _check_earlier_output(p: Path, shown: str, entries: list[str], overwrite: bool,
                          marker: str, option: str) -> None:
    """Refuse to replace ``p`` unless it is an earlier output of this kind (``marker``) that
    holds only the files its manifest lists, and ``overwrite``."""
    found, manifest = read_marker(p)
    if found is None:
        raise OutputError(f"{option} {shown} is a folder with files cardionurbs did not "
                          "write: choose a new or empty folder", option=option)
    if found != marker:
        what = ("a study cardionurbs generated (phantom): an output never replaces a study"
                if found == STUDY_MARKER else "an analysis output, not a generated study")
        raise OutputError(f"{option} {shown} is {what}; choose a new or empty folder",
                          option=option)
    if manifest is None:
        raise OutputError(f"{option} {shown}: its marker {found} lists no files (an older "
                          "cardionurbs wrote it), so what may be replaced is unknown: remove "
                          "the folder yourself or choose another", option=option)
    extra = foreign_files(p, manifest)
    if extra:
        named = ", ".join(extra[:3]) + (f" and {len(extra) - 3} more" if len(extra) > 3 else "")
        raise OutputError(f"{option} {shown} holds files cardionurbs did not write ({named}): "
                          "move them away or choose another folder", option=option)
    if not overwrite:
        raise OutputError(f"{option} {shown} holds an earlier cardionurbs output: pass "
                          "--overwrite to replace it", option=option)


def _resolved(p: str | os.PathLike) -> Path:
    return Path(os.path.abspath(os.path.realpath(os.fspath(p))))


def _relation(a: Path, b: Path) -> str | None:
    """How resolved path ``a`` relates to ``b``: 'is', 'inside', 'contains' or None."""
    if a == b:
        return "is"
    if a.is_relative_to(b):
        return "inside"
    if b.is_relative_to(a):
        return "contains"
    return None


def _check_against_inputs(out: Path, shown: str, inputs: Iterable, option: str) -> None:
    words = {"is": "is", "inside": "lies inside", "contains": "contains"}
    for inp in inputs:
        if inp is None:
            continue
        rel = _relation(out, _resolved(inp))
        if rel is not None:
            raise OutputError(f"{option} {shown} {words[rel]} the input {inp}: choose a folder "
                              "outside the study", option=option)
    cwd = _resolved(os.getcwd())
    if out == cwd or cwd.is_relative_to(out):
        raise OutputError(f"{option} {shown} {'is' if out == cwd else 'contains'} the current "
                          "folder: choose a new folder (e.g. a name that does not exist yet)",
                          option=option)


#: room a temporary sibling's name needs beyond the output's own (``.<name>.<pid>-<8>.tmp``)
_TEMP_NAME_ROOM = 32


def _check_name_length(p: Path, shown: str, option: str) -> None:
    """Refuse, before any work, a name the file system cannot hold with its temporary
    sibling's decoration (NAME_MAX, usually 255 bytes)."""
    try:
        limit = os.pathconf(p.parent if str(p.parent) and p.parent.exists() else ".",
                            "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    n = len(os.fsencode(p.name))
    if n > limit - _TEMP_NAME_ROOM:
        raise OutputError(f"{option}: the name {excerpt(p.name)} is {n} bytes long; at most "
                          f"{limit - _TEMP_NAME_ROOM} fit this file system", option=option)
    if len(os.fsencode(os.path.abspath(p))) > 4000:
        raise OutputError(f"{option}: the path is too long ({excerpt(shown)})", option=option)


def check_output_dir(out: str | os.PathLike, *, inputs: Iterable = (), overwrite: bool = False,
                     option: str = "--out", marker: str = MARKER) -> Path:
    """Check that ``out`` may become this command's output folder; return it as given.

    ``inputs`` are the files or folders the command reads (a study folder, its
    manifest): ``out`` may not be, contain or lie inside any of them. ``out``
    must be absent, empty, or -- with ``overwrite`` -- an earlier cardionurbs
    output of the same kind (``marker``: :data:`MARKER` for outputs, :data:`STUDY_MARKER`
    for ``phantom``) holding only the files its manifest lists. Stale temporaries of
    killed runs beside ``out`` are removed. Raises :class:`OutputError` naming ``option``.

    Parameters
    ----------
    out : str or os.PathLike
        The output folder asked for.
    inputs : iterable of path-like
        What the command reads.
    overwrite : bool
        Allow replacing an earlier cardionurbs output of the same kind.
    option : str
        The option that named ``out``, for the message (``--out``).
    marker : str
        The kind of output (:data:`~cardionurbs.io.atomic.MARKER` or
        :data:`~cardionurbs.io.atomic.STUDY_MARKER`).

    Returns
    -------
    pathlib.Path
        ``out``.

    Raises
    ------
    OutputError
        ``out`` may not be written (naming ``option`` and why).
    """
    shown = os.fspath(out)
    p = Path(out)
    _check_name_length(p, shown, option)
    if p.is_symlink():
        raise OutputError(f"{option} {shown} is a symbolic link: give the real folder",
                          option=option)
    resolved = _resolved(p)
    _check_against_inputs(resolved, shown, inputs, option)
    if p.exists() and not p.is_dir():
        raise OutputError(f"{option} {shown} is an existing file, not a folder", option=option)
    if p.parent.exists() and not p.parent.is_dir():
        raise OutputError(f"{option} {shown}: {p.parent} is a file, not a folder", option=option)
    remove_stale_temporaries(p)
    if p.is_dir():
        try:
            entries = [e.name for e in os.scandir(p)]
        except OSError as exc:
            raise OutputError(f"{option} {shown} cannot be listed ({exc.strerror})",
                              option=option) from None
        if entries:
            _check_earlier_output(p, shown, entries, overwrite, marker, option)
    return p


def check_output_place(out: str | os.PathLike, *, inputs: Iterable = (),
                       option: str = "--run-dir") -> Path:
    """Check that the folder ``out`` (which may exist and be reused, e.g. ``--run-dir``) is
    neither a symbolic link nor a file, and neither is, contains nor lies inside any of
    ``inputs`` (a study). Returns it as given; raises :class:`OutputError` naming ``option``.

    Parameters
    ----------
    out : str or os.PathLike
        The folder asked for.
    inputs : iterable of path-like
        What the command reads.
    option : str
        The option that named ``out``, for the message.

    Returns
    -------
    pathlib.Path
        ``out``.

    Raises
    ------
    OutputError
        A link, a file, or a place overlapping the inputs.
    """
    shown = os.fspath(out)
    p = Path(out)
    if p.is_symlink():
        raise OutputError(f"{option} {shown} is a symbolic link: give the real folder",
                          option=option)
    if p.exists() and not p.is_dir():
        raise OutputError(f"{option} {shown} is an existing file, not a folder", option=option)
    _check_against_inputs(_resolved(p), shown, inputs, option)
    return p


def check_output_file(out: str | os.PathLike, *, inputs: Iterable = (), option: str = "--out",
                      ours=None, overwrite: bool = False) -> Path:
    """Check that ``out`` may become this command's output file; return it as given.

    An existing folder or symbolic link is refused; so is a path that is one of
    ``inputs`` or lies inside an input folder, or contains an input. An existing
    regular file elsewhere is replaced atomically when the command succeeds (the
    usual ``-o FILE`` behaviour) -- unless ``ours`` is given (a test ``path -> bool`` that
    tells a file this package wrote): then a file it did not write needs ``overwrite``.
    Stale temporaries beside ``out`` are removed.

    Parameters
    ----------
    out : str or os.PathLike
        The output file asked for.
    inputs : iterable of path-like
        What the command reads.
    option : str
        The option that named ``out``, for the message (``--out``).
    ours : callable or None
        ``ours(path) -> bool``: whether an existing file was written by this package.
    overwrite : bool
        Allow replacing a file ``ours`` does not recognise.

    Returns
    -------
    pathlib.Path
        ``out``.

    Raises
    ------
    OutputError
        ``out`` may not be written (naming ``option`` and why).
    """
    shown = os.fspath(out)
    p = Path(out)
    _check_name_length(p, shown, option)
    if p.is_symlink():
        raise OutputError(f"{option} {shown} is a symbolic link: give a real file name",
                          option=option)
    if p.is_dir():
        raise OutputError(f"{option} {shown} is an existing folder, not a file", option=option)
    if p.parent.exists() and not p.parent.is_dir():
        raise OutputError(f"{option} {shown}: {p.parent} is a file, not a folder", option=option)
    resolved = _resolved(p)
    for inp in inputs:
        if inp is None:
            continue
        rel = _relation(resolved, _resolved(inp))
        if rel is not None:
            words = {"is": "is", "inside": "lies inside", "contains": "contains"}[rel]
            raise OutputError(f"{option} {shown} {words} the input {inp}: write it elsewhere",
                              option=option)
    if ours is not None and p.is_file() and not overwrite and not ours(p):
        raise OutputError(f"{option} {shown} is an existing file cardionurbs did not write: "
                          "pass --overwrite to replace it, or choose another name", option=option)
    remove_stale_temporaries(p)
    return p
