"""A seeded fuzz corpus of mutated studies and the exit contract it must keep (issue 31).

Five small base studies -- native (study.json + points.csv), GPFile, Sunnybrook (DICOM +
contour text), DICOM headers (of that Sunnybrook study) and a NIfTI label map -- are
built once; :func:`cases` then draws ``n`` mutations from ``random.Random(seed)``:
edited JSON values, replaced / dropped / duplicated / truncated lines, flipped bytes,
DICOM attributes set to text, huge or NaN values, NIfTI header fields (dims,
datatype, pixdim, vox_offset, sform) overwritten, gzip streams cut, and files swapped for
symbolic links to a file outside the study.

For every case :func:`run_case` checks the contract of the README:

* ``load_study`` returns a study or raises a CardioNurbsError (one line) -- never
  another exception; a failed load makes ``cardionurbs analyze`` exit 2 with one line
  on stderr and nothing written; ``--sample-analyze`` also runs ``analyze`` on a share
  of the cases that load (exit 0 or 2, one line on error);
* no file outside the study is opened (an ``open`` audit hook, paths resolved) and no
  file is written outside ``--out`` (the case's folder is compared before and after);
* no process the run started is left alive.

Run whole (the counts go to reports/limits.md)::

    nice -n 10 .venv/bin/python benchmarks/fuzz_inputs.py --n 500 --seed 31

The test suite runs a small sample (tests/test_fuzz_inputs.py).
"""

from __future__ import annotations

import argparse
import gzip
import io
import json
import os
import random
import shutil
import struct
import sys
import tempfile
import time
from collections import Counter
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
from procs import children  # noqa: E402 (tests/ is on the path now)

KINDS = ("native", "gpfile", "sunnybrook", "dicom", "nifti")
SECRET = "FUZZ-SECRET outside the study"

# ------------------------------------------------------------------ open() audit
_WATCH: dict = {"on": False, "opened": []}


def _audit(event, args):
    if _WATCH["on"] and event == "open" and args and isinstance(args[0], (str, bytes, os.PathLike)):
        _WATCH["opened"].append(os.fsdecode(args[0]))


sys.addaudithook(_audit)
_ALLOWED = [Path(p).resolve() for p in {sys.prefix, sys.base_prefix, sys.exec_prefix,
                                           *sys.path[1:]} if p and Path(p).is_dir()
            and Path(p).resolve() != Path("/")] + [ROOT / "cardionurbs"]


def outside_opens(study: Path, opened: list[str]) -> list[str]:
    """Files in ``opened`` that resolve neither inside ``study`` nor inside Python's own
    trees or the package (code, fonts, package data)."""
    roots = [study.resolve()] + _ALLOWED
    bad = []
    for p in opened:
        if p.startswith(("/proc/", "/dev/", "/sys/")):
            continue
        r = Path(os.path.realpath(p))
        if not any(r.is_relative_to(root) for root in roots):
            bad.append(p)
    return bad


# ------------------------------------------------------------------ the bases
def _nifti_base(root: Path) -> Path:
    """A 48 x 48 x 6 x 2 label map (LV 3 inside myocardium 2, RV 1 beside), gzip NIfTI-1."""
    import nibabel as nib
    import numpy as np
    root.mkdir(parents=True)
    yy, xx = np.mgrid[:48, :48]
    vol = np.zeros((48, 48, 6, 2), np.uint8)
    for t, s in enumerate((1.0, 0.8)):
        r = np.hypot(xx - 22, yy - 24)
        vol[..., :, t][r < 12 * s] = 2
        vol[..., :, t][r < 8 * s] = 3
        rv = np.hypot((xx - 36) / 1.6, yy - 24)
        vol[..., :, t][(rv < 7 * s) & (r >= 12 * s)] = 1
    vol[..., 0, :] = 0
    aff = np.diag([1.5, 1.5, 8.0, 1.0])
    img = nib.Nifti1Image(vol, aff)
    img.header.set_xyzt_units("mm", "msec")
    img.header["pixdim"][4] = 40.0
    nib.save(img, root / "map.nii.gz")
    return root


def make_bases(root: Path) -> dict[str, Path]:
    """The five base studies under ``root`` (seconds; deterministic)."""
    from broken.corpus import make_gpfile, make_native, make_sunnybrook
    sb = make_sunnybrook(root / "sunnybrook")
    return {"native": make_native(root / "native"), "gpfile": make_gpfile(root / "gpfile"),
            "sunnybrook": sb, "dicom": sb, "nifti": _nifti_base(root / "nifti")}


# ------------------------------------------------------------------ mutations
WILD_TEXT = ["", "abc", "nan", "inf", "-inf", "1e308", "-1e308", "1e-320", "-5", "500",
             "0", "-0", "1.5", "9" * 300, "\u00e9\u00e8\u4e2d", "a,b", "\t", "\x00", "..",
             "/etc/passwd", "../x", "1 2 3", "True", "[]", "{}", "null", "9" * 20]
WILD_JSON = [None, True, False, 0, -1, 1e308, float("nan"), float("inf"), 2**63, -2**40,
             "", "abc", "../x", "/etc/passwd", [], {}, [1, 2], {"a": 1}, "x" * 1000, 0.5]


def _json_paths(v, prefix=()):
    yield prefix
    if isinstance(v, dict):
        for k, x in v.items():
            yield from _json_paths(x, prefix + (k,))
    elif isinstance(v, list):
        for i, x in enumerate(v[:3]):
            yield from _json_paths(x, prefix + (i,))


def mutate_json(study: Path, rnd: random.Random) -> str:
    p = study / "study.json"
    m = json.loads(p.read_text())
    paths = [q for q in _json_paths(m) if q]
    path = rnd.choice(paths)
    d = m
    for k in path[:-1]:
        d = d[k]
    if rnd.random() < 0.2 and isinstance(d, dict):
        del d[path[-1]]
        what = f"study.json: del {'.'.join(map(str, path))}"
    else:
        d[path[-1]] = value = rnd.choice(WILD_JSON)
        what = f"study.json: {'.'.join(map(str, path))} = {str(value)[:20]!r}"
    p.write_text(json.dumps(m, allow_nan=True))
    return what


def mutate_lines(p: Path, rnd: random.Random, sep: str) -> str:
    data = p.read_bytes()
    op = rnd.choice(["field", "field", "field", "truncate", "drop", "dup", "byte", "empty"])
    if op == "truncate":
        p.write_bytes(data[:rnd.randrange(max(1, len(data)))])
        return f"{p.name}: truncated"
    if op == "byte":
        b = bytearray(data)
        b[rnd.randrange(len(b))] = rnd.randrange(256)
        p.write_bytes(bytes(b))
        return f"{p.name}: a byte flipped"
    if op == "empty":
        p.write_bytes(b"")
        return f"{p.name}: emptied"
    lines = data.decode("utf-8", "replace").splitlines()
    k = rnd.randrange(len(lines))
    if op == "drop":
        del lines[k]
    elif op == "dup":
        lines.insert(k, lines[k])
    else:
        fields = lines[k].split(sep)
        j = rnd.randrange(len(fields))
        fields[j] = rnd.choice(WILD_TEXT)
        lines[k] = sep.join(fields)
        op = f"line {k + 1} field {j + 1} = {fields[j][:12]!r}"
    p.write_text("\n".join(lines) + "\n")
    return f"{p.name}: {op}"


def link_out(p: Path, outside: Path) -> str:
    """Replace ``p`` (a file or folder of the study) by a link to a copy outside it."""
    target = outside / ("moved-" + p.name)
    if p.is_dir():
        shutil.copytree(p, target)
        shutil.rmtree(p)
    else:
        shutil.copy(p, target)
        p.unlink()
    os.symlink(target, p)
    return f"{p.name}: a link leading out"


_DICOM_TAGS = ["ImagePositionPatient", "ImageOrientationPatient", "PixelSpacing", "Rows",
               "Columns", "TriggerTime", "InstanceNumber", "SliceThickness", "PatientID",
               "SOPInstanceUID", "HeartRate", "NominalInterval", "SeriesInstanceUID",
               "BitsAllocated", "SamplesPerPixel"]


def mutate_dicom(study: Path, rnd: random.Random) -> str:
    import pydicom
    f = rnd.choice(sorted((study / "dicom").glob("*.dcm")))
    if rnd.random() < 0.15:
        data = f.read_bytes()
        f.write_bytes(data[:rnd.randrange(len(data))])
        return f"{f.name}: truncated"
    ds = pydicom.dcmread(f)
    tag = rnd.choice(_DICOM_TAGS)
    try:
        if rnd.random() < 0.2:
            delattr(ds, tag)
            what = f"del {tag}"
        else:
            text = rnd.choice(WILD_TEXT + ["1e308\\0\\0", "0\\0\\0\\0\\0\\0", "1\\2"])
            setattr(ds, tag, text)
            what = f"{tag} = {text[:16]!r}"
        ds.save_as(f)
    except Exception:  # noqa: BLE001 - pydicom would not write that value: a byte instead
        b = bytearray(f.read_bytes())
        b[rnd.randrange(132, len(b))] = rnd.randrange(256)
        f.write_bytes(bytes(b))
        what = "a byte flipped"
    return f"{f.name}: {what}"


# NIfTI-1 header fields: (offset, struct format, wild values)
_NIFTI_FIELDS = {"dim": (40, "<8h", [(4, 48, 48, 6, 600, 1, 1, 1), (3, 32767, 32767, 32767, 1, 1, 1, 1),
                                     (0, 0, 0, 0, 0, 0, 0, 0), (7, 2, 2, 2, 2, 2, 2, 2),
                                     (4, -1, 48, 6, 2, 1, 1, 1), (4, 48, 48, 6, 0, 1, 1, 1)]),
                 "datatype": (70, "<h", [(255,), (0,), (16,), (64,), (2304,), (-1,)]),
                 "bitpix": (72, "<h", [(0,), (7,), (128,)]),
                 "pixdim": (76, "<8f", [(1, 0, 0, 0, 0, 0, 0, 0), (1, float("nan"), 1, 1, 1, 0, 0, 0),
                                        (1, 1e38, 1e38, 1e38, 1, 0, 0, 0), (-1, -1, -1, -1, -1, 0, 0, 0)]),
                 "vox_offset": (108, "<f", [(0.0,), (1e30,), (-1.0,), (float("nan"),), (349.0,)]),
                 "sform": (280, "<12f", [(0.0,) * 12, (float("nan"),) * 12, (1e38,) * 12]),
                 "sform_code": (254, "<h", [(5,), (-3,), (0,)]),
                 "magic": (344, "4s", [(b"n+2\0",), (b"xxxx",)])}


def mutate_nifti(study: Path, rnd: random.Random) -> str:
    f = study / "map.nii.gz"
    raw = bytearray(gzip.decompress(f.read_bytes()))
    op = rnd.random()
    if op < 0.15:
        data = f.read_bytes()
        f.write_bytes(data[:rnd.randrange(len(data))])
        return "map.nii.gz: gzip stream cut"
    if op < 0.25:
        f.write_bytes(gzip.compress(bytes(raw[:rnd.randrange(len(raw))])))
        return "map.nii.gz: voxel data cut"
    if op < 0.35:
        k = rnd.randrange(352, len(raw))
        raw[k] = rnd.choice([4, 7, 255])
        f.write_bytes(gzip.compress(bytes(raw)))
        return "map.nii.gz: a voxel set to a stray label"
    name = rnd.choice(sorted(_NIFTI_FIELDS))
    off, fmt, values = _NIFTI_FIELDS[name]
    v = rnd.choice(values)
    raw[off:off + struct.calcsize(fmt)] = struct.pack(fmt, *v)
    f.write_bytes(gzip.compress(bytes(raw)))
    return f"map.nii.gz: {name} = {str(v)[:30]}"


@dataclass
class Case:
    """One mutated study: its base kind, the seed of its mutation and what was done."""

    index: int
    kind: str
    seed: int
    what: str = ""


def build(case: Case, bases: dict[str, Path], work: Path) -> Path:
    """Copy the case's base into ``work/study`` and mutate it; returns the study folder."""
    rnd = random.Random(case.seed)
    study = Path(shutil.copytree(bases[case.kind], work / "study", symlinks=True))
    outside = work / "outside"
    outside.mkdir(exist_ok=True)
    (outside / "secret.txt").write_text(SECRET + "\n")
    if rnd.random() < 0.06:                         # a link leading out, of some file or folder
        choices = sorted(p for p in study.rglob("*") if p.name != ".cardionurbs-study")
        case.what = link_out(rnd.choice(choices), outside)
        return study
    if case.kind == "native":
        case.what = (mutate_json(study, rnd) if rnd.random() < 0.5
                     else mutate_lines(study / "points.csv", rnd, ","))
    elif case.kind == "gpfile":
        files = sorted(study.glob("GPFile_*.txt")) + [study / "SliceInfoFile.txt"]
        case.what = mutate_lines(rnd.choice(files), rnd, "\t")
    elif case.kind == "sunnybrook":
        case.what = mutate_lines(rnd.choice(sorted(study.rglob("*contour-manual.txt"))), rnd, " ")
    elif case.kind == "dicom":
        case.what = mutate_dicom(study, rnd)
    else:
        case.what = mutate_nifti(study, rnd)
    return study


def cases(n: int, seed: int = 31) -> list[Case]:
    """``n`` cases, the kinds in turn, each with its own seed drawn from ``seed``."""
    rnd = random.Random(seed)
    return [Case(i, KINDS[i % len(KINDS)], rnd.randrange(2**32)) for i in range(n)]


# ------------------------------------------------------------------ the contract
def _tree(folder: Path) -> dict[str, tuple]:
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_symlink() or p.is_file():
            st = p.lstat()
            out[p.relative_to(folder).as_posix()] = (st.st_size, st.st_mtime_ns)
    return out


def _new_children(already: set[int], grace_s: float = 1.0) -> list[int]:
    """This process's children that were not among ``already``, once those that are
    exiting have had ``grace_s`` seconds to go."""
    import time
    deadline = time.monotonic() + grace_s
    while True:
        new = [p for p in children(os.getpid()) if p not in already]
        if not new or time.monotonic() > deadline:
            return new
        time.sleep(0.05)


def run_case(case: Case, bases: dict[str, Path], work: Path, analyze_ok: bool = False) -> dict:
    """Build and check one case; returns its record (``problems`` empty when the contract
    holds). ``analyze_ok``: also run ``analyze`` when the study loads."""
    from cardionurbs import load_study
    from cardionurbs.cli import main
    from cardionurbs.errors import CardioNurbsError

    study = build(case, bases, work)
    target = study / "map.nii.gz" if case.kind == "nifti" else study
    problems: list[str] = []
    already = set(children(os.getpid()))      # a test runner's own children are not this case's
    _WATCH["opened"], _WATCH["on"] = [], True
    try:
        load_study(target)
        loaded, message = True, ""
    except CardioNurbsError as exc:
        loaded, message = False, str(exc)
        if "\n" in message:
            problems.append("multi-line error")
        if SECRET in message:
            problems.append("echoed a file outside the study")
    except Exception as exc:  # noqa: BLE001 - the contract's failure, recorded
        loaded, message = False, f"{type(exc).__name__}: {exc}"
        problems.append(f"internal error {type(exc).__name__}")
    finally:
        _WATCH["on"] = False
    bad = outside_opens(study, _WATCH["opened"])
    if bad:
        problems.append(f"opened outside the study: {bad[0]}")
    code = None
    if not loaded or analyze_ok:
        before = _tree(work)
        out = work / "out"
        err = io.StringIO()
        with redirect_stderr(err), redirect_stdout(io.StringIO()):
            code = main(["analyze", str(target), "--out", str(out), "--outputs", "metrics"])
        text = err.getvalue()
        if code not in (0, 2):
            problems.append(f"analyze exit {code}: {text.strip()[:200]}")
        if code == 2 and (text.count("\n") != 1 or not text.startswith("cardionurbs: error: ")):
            problems.append(f"stderr not one line: {text[:200]!r}")
        if "Traceback" in text:
            problems.append("traceback")
        after = _tree(work)
        wrote = [k for k in after if after[k] != before.get(k) and not k.startswith("out/")]
        if wrote:
            problems.append(f"wrote outside --out: {wrote[0]}")
        if code == 2 and out.exists():
            problems.append("half-written output")
    if _new_children(already):
        problems.append("a process left alive")
    return {"index": case.index, "kind": case.kind, "what": case.what, "loaded": loaded,
            "exit": code, "message": message[:160], "problems": problems}


def run(n: int, seed: int, analyze_share: float = 0.0) -> list[dict]:
    """Every case of :func:`cases` in a fresh temporary folder; the records."""
    from cardionurbs.safe import quiet_third_party
    quiet_third_party()
    records = []
    with tempfile.TemporaryDirectory(prefix="cn-fuzz-") as tmp:
        bases = make_bases(Path(tmp) / "bases")
        pick = random.Random(seed + 1)
        for case in cases(n, seed):
            work = Path(tmp) / f"case{case.index:04d}"
            work.mkdir()
            records.append(run_case(case, bases, work, analyze_ok=pick.random() < analyze_share))
            shutil.rmtree(work, ignore_errors=True)
    return records


def summary(records: list[dict]) -> dict:
    """Counts for reports/limits.md."""
    c = Counter()
    for r in records:
        c["cases"] += 1
        c[f"kind {r['kind']}"] += 1
        c["loaded"] += r["loaded"]
        c["exit 2"] += r["exit"] == 2
        c["exit 0"] += r["exit"] == 0
        c["contract broken"] += bool(r["problems"])
        for p in r["problems"]:
            c["problem: " + p.split(":")[0]] += 1
    return dict(c)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--seed", type=int, default=31)
    ap.add_argument("--analyze-share", type=float, default=0.05,
                    help="share of the loading cases also run through analyze")
    ap.add_argument("--json", type=Path, default=None, help="write every record here")
    args = ap.parse_args(argv)
    t = time.perf_counter()
    records = run(args.n, args.seed, args.analyze_share)
    s = summary(records)
    s["seconds"] = round(time.perf_counter() - t, 1)
    print(json.dumps(s, indent=1))
    for r in records:
        if r["problems"]:
            print(f"case {r['index']} ({r['kind']}, {r['what']}): {'; '.join(r['problems'])}")
    if args.json:
        args.json.write_text(json.dumps(records, indent=1))
    return 1 if s.get("contract broken") else 0


if __name__ == "__main__":
    sys.exit(main())
