"""The same bytes every run (issue 31, Done-when): ``analyze`` with every output, run
several times in fresh processes (each with its own string-hash seed), ``--jobs 1`` and
``--jobs 2``, compared file by file, byte for byte, ``model.3dm`` included.

    nice -n 10 .venv/bin/python benchmarks/same_bytes.py --frames 2

Prints one line per run (files, bytes, files differing from the first run of the same
mesh format) and exits 1 when any file differs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: (name, jobs, PYTHONHASHSEED, mesh format) of each run
RUNS = [("a", "1", "1", "ply"), ("b", "1", "2", "ply"), ("c", "2", "3", "ply"),
        ("d", "1", "4", "vtp"), ("e", "2", "5", "vtp")]


def _cli(*args: str, seed: str = "0") -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONHASHSEED=seed)
    subprocess.run([sys.executable, "-m", "cardionurbs.cli", *args], env=env, check=True,
                   stdout=subprocess.DEVNULL)


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--pathology", default="normal")
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="cn-bytes-"))
    _cli("phantom", "--pathology", args.pathology, "--frames", str(args.frames), "--no-dicom",
         "--out", str(tmp / "study"))
    first: dict[str, dict[str, bytes]] = {}
    bad = 0
    for name, jobs, seed, fmt in RUNS:
        _cli("analyze", str(tmp / "study"), "--out", str(tmp / name), "--jobs", jobs,
             "--mesh-format", fmt, seed=seed)
        files = _files(tmp / name)
        ref = first.setdefault(fmt, files)
        differ = sorted(k for k in ref.keys() | files.keys() if ref.get(k) != files.get(k))
        bad += bool(differ)
        print(f"run {name} (--jobs {jobs}, PYTHONHASHSEED={seed}, {fmt}): {len(files)} files, "
              f"{sum(map(len, files.values()))} bytes, model.3dm {'model.3dm' in files}; "
              f"differ from the first {fmt} run: {differ or 'none'}", flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
