"""Write files so that a reader never sees a half-written one: temp file, then rename.

Temporaries are hidden siblings named ``.<name>.<pid>-<random>.tmp`` (files
and folders alike), so that the next run can tell those of a killed process
(its pid no longer alive) from those of a run still going, and remove them
(:func:`remove_stale_temporaries`). Files and folders are created with the
permissions of the process umask (``0666 & ~umask``, ``0777 & ~umask``), as
``open()`` and ``mkdir()`` would, not ``mkstemp``'s 0600.
"""

from __future__ import annotations

import ctypes
import os
import re
import shutil
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

#: file that marks a folder as an output cardionurbs wrote (analyze, track, demo, ...):
#: JSON listing the files it wrote (see cardionurbs.io.outputs)
MARKER = ".cardionurbs-output"
#: the marker of a *study* cardionurbs generated (phantom): no output command replaces it
STUDY_MARKER = ".cardionurbs-study"
MARKERS = (MARKER, STUDY_MARKER)
MARKER_TEXT = "This folder was written by cardionurbs; --overwrite may replace it whole.\n"


def write_marker(folder: str | os.PathLike, marker: str = MARKER, *,
                 trees: tuple[str, ...] | list[str] = ()) -> Path:
    """Write ``marker`` into ``folder``: JSON naming the files cardionurbs wrote there
    (every regular file now under ``folder``, sorted, POSIX relative paths) and the
    ``trees`` (subfolders) it owns whole; the same content gives the same bytes.

    Parameters
    ----------
    folder : path-like
        The output (or temporary) folder, complete.
    marker : str
        :data:`MARKER` for outputs, :data:`STUDY_MARKER` for generated studies.
    trees : sequence of str
        Subfolder names written whole (e.g. the subjects of a phantom cohort).

    Returns
    -------
    Path
        The marker file."""
    import json
    folder = Path(folder)
    files = sorted(rel for rel in _tree_files(folder) if rel not in MARKERS)
    doc = {"written_by": "cardionurbs", "kind": "study" if marker == STUDY_MARKER else "output",
           "files": files, "trees": sorted(trees)}
    path = folder / marker
    path.write_text(json.dumps(doc, indent=0) + "\n", encoding="utf-8")
    return path


def _tree_files(folder: Path) -> list[str]:
    """Every non-folder entry under ``folder`` (links not followed), as POSIX relative paths."""
    out = []
    for dirpath, dirnames, filenames in os.walk(folder):
        base = Path(dirpath).relative_to(folder)
        out += [(base / n).as_posix() for n in filenames]
        out += [(base / n).as_posix() for n in dirnames if os.path.islink(os.path.join(dirpath, n))]
    return out


def read_marker(folder: str | os.PathLike) -> tuple[str | None, dict | None]:
    """(the marker's name, its manifest) of ``folder``: (None, None) without a marker, the
    name and None for a marker without a readable manifest (an older cardionurbs).

    Parameters
    ----------
    folder : str or os.PathLike
        A folder that may hold a cardionurbs marker (:data:`MARKERS`).

    Returns
    -------
    name : str or None
        The marker's file name, None without one.
    manifest : dict or None
        Its manifest (``files``, ``trees``), None when absent or unreadable.
    """
    import json
    for name in MARKERS:
        path = Path(folder) / name
        if path.is_file() and not path.is_symlink():
            try:
                doc = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, ValueError):
                return name, None
            ok = (isinstance(doc, dict) and isinstance(doc.get("files"), list)
                  and isinstance(doc.get("trees", []), list))
            return name, doc if ok else None
    return None, None

_umask_lock = threading.Lock()


def current_umask() -> int:
    """The process umask (read without changing it on Linux, else set and restored).

    Returns
    -------
    int
        The umask bits (e.g. ``0o022``).
    """
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _umask_lock:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def _prefix(path: Path) -> str:
    return f".{path.name}.{os.getpid()}-"


_TEMP = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)-[^.]*\.(?:tmp|old)$")


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def remove_stale_temporaries(path: str | os.PathLike) -> list[Path]:
    """Remove the temporaries that killed runs left beside ``path`` (hidden
    ``.<name>.<pid>-*.tmp`` / ``.old`` siblings whose process is gone); temporary
    folders only when they hold the cardionurbs marker. When ``path`` itself is
    missing but a killed run left the previous output as ``.<name>.<pid>-*.old``,
    that output is put back first. Returns what was removed.

    Parameters
    ----------
    path : str or os.PathLike
        The output path whose hidden siblings are examined.

    Returns
    -------
    list of pathlib.Path
        The temporaries removed.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        return []
    removed: list[Path] = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return []
    for e in sorted(entries, key=lambda e: e.name):
        m = _TEMP.match(e.name)
        if not m or m.group("name") != path.name or _pid_alive(int(m.group("pid"))):
            continue
        q = Path(e.path)
        if q.is_symlink():
            continue
        if q.is_dir():
            if not any((q / m).is_file() for m in MARKERS):
                continue
            if e.name.endswith(".old") and not path.exists():
                os.replace(q, path)             # the previous output, put back
                continue
            shutil.rmtree(q, ignore_errors=True)
        else:
            q.unlink(missing_ok=True)
        removed.append(q)
    return removed


def _chmod_umask(path: Path, base: int) -> None:
    os.chmod(path, base & ~current_umask())


def sibling_temporary_dir(path: str | os.PathLike, marker: str = MARKER) -> Path:
    """A new temporary folder beside ``path``, named and marked as :func:`atomic_dir`'s (so
    that :func:`remove_stale_temporaries` removes it when its process was killed); the
    caller removes it, or renames it into place after deleting ``marker`` from it.

    Parameters
    ----------
    path : str or os.PathLike
        The output folder the temporary one is beside (``path`` need not exist).
    marker : str
        The marker file written into it (:data:`MARKER` or :data:`STUDY_MARKER`).

    Returns
    -------
    pathlib.Path
        The new, marked, empty folder.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=_prefix(path), suffix=".tmp", dir=path.parent))
    try:
        _chmod_umask(tmp, 0o777)
        (tmp / marker).write_text(MARKER_TEXT, encoding="utf-8")
    except BaseException:             # unmarked, it would not be recognised as debris later
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    On an exception (or an interrupt) the temporary file is removed and ``path``
    is untouched. The file gets the umask's permissions.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.

    Yields
    ------
    pathlib.Path
        The temporary path to write to.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=_prefix(path), suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        _chmod_umask(tmp_path, 0o666)
        yield tmp_path
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Atomically write UTF-8 text.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (replaced whole, or untouched on failure).
    text : str
        Its content, written as UTF-8.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Atomically write bytes.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (replaced whole, or untouched on failure).
    data : bytes
        Its content.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap two existing paths (Linux renameat2 RENAME_EXCHANGE); False when
    the system cannot."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    rc = fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    return rc == 0


@contextmanager
def atomic_dir(path: str | os.PathLike, marker: str = MARKER) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; on success it replaces ``path``.

    Used for whole outputs (a phantom study, an analysis folder) so that a
    failure or an interrupt leaves no half-written folder behind and the
    previous content intact. The marker (:data:`MARKER`, or :data:`STUDY_MARKER` for a
    generated study) is written first, so the result (and any debris of a killed run)
    is recognisable as cardionurbs output, and rewritten at the end with the list of
    files written (:func:`write_marker`), which is all ``--overwrite`` may replace. An existing ``path`` is swapped with the new content in one atomic
    step where the system allows (Linux ``renameat2``), else renamed aside just
    before; callers check ``path`` first (:func:`cardionurbs.io.outputs.check_output_dir`).

    Parameters
    ----------
    path : str or os.PathLike
        The output folder.
    marker : str
        The marker written into it: :data:`MARKER` (outputs) or :data:`STUDY_MARKER` (a
        generated study).

    Yields
    ------
    pathlib.Path
        The temporary folder to write into.
    """
    path = Path(path)
    tmp = sibling_temporary_dir(path, marker)
    try:
        yield tmp
        write_marker(tmp, marker)
        if path.exists():
            if _exchange(tmp, path):
                shutil.rmtree(tmp, ignore_errors=True)   # now holds the previous output
                return
            old = Path(tempfile.mkdtemp(prefix=_prefix(path), suffix=".old", dir=path.parent))
            os.rmdir(old)
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
