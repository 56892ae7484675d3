"""Seeded fuzzing of every input format (issue 10): mutated study.json, points.csv,
Sunnybrook contours, GPFile lines and DICOM headers give exit 0 or 2 only -- a StudyError
or a study, never another exception -- one line on stderr, nothing left behind on failure,
and no file outside the study opened (watched with an audit hook on ``open``).

Bounded to about a minute on two cores: loading is fuzzed for every example; the full
``analyze`` runs for every example whose load fails (exit 2 must come before any work) and
for the Sunnybrook examples (the quickest to reconstruct).
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pydicom
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from broken.corpus import make_gpfile, make_native, make_sunnybrook
from cardionurbs import load_study
from cardionurbs.cli import main
from cardionurbs.errors import CardioNurbsError

# ------------------------------------------------------------------ open() audit
def _corpus():
    import importlib.util
    if "fuzz_inputs" in sys.modules:
        return sys.modules["fuzz_inputs"]
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "fuzz_inputs.py"
    spec = importlib.util.spec_from_file_location("fuzz_inputs", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["fuzz_inputs"] = mod
    spec.loader.exec_module(mod)
    return mod


# the corpus module's open() audit (an audit hook) serves the hypothesis cases too
_WATCH = _corpus()._WATCH


# ----------------------------------------------------------------------- bases
@pytest.fixture(scope="module")
def bases(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("fuzz_bases")
    return {"native": make_native(root / "native"), "sunnybrook": make_sunnybrook(root / "sb"),
            "gpfile": make_gpfile(root / "gp")}


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-2**40, 2**40)
    | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=20),
    lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=5), c, max_size=3),
    max_leaves=6)
TEXT = st.text(st.characters(blacklist_categories=("Cs",)), max_size=30)


def _json_paths(v, prefix=()):
    yield prefix
    if isinstance(v, dict):
        for k, x in v.items():
            yield from _json_paths(x, prefix + (k,))
    elif isinstance(v, list):
        for i, x in enumerate(v[:3]):
            yield from _json_paths(x, prefix + (i,))


@st.composite
def mutations(draw):
    kind = draw(st.sampled_from(["study.json", "points.csv", "sunnybrook", "gpfile", "dicom"]))
    return kind, draw(st.randoms(use_true_random=False))


def _mutate_json(study: Path, rnd, value) -> None:
    p = study / "study.json"
    m = json.loads(p.read_text())
    paths = [q for q in _json_paths(m) if q and not (q[0] == "images" and len(q) > 3)]
    path = rnd.choice(paths)
    d = m
    for k in path[:-1]:
        d = d[k]
    if rnd.random() < 0.2 and isinstance(d, dict):
        del d[path[-1]]
    else:
        d[path[-1]] = value
    p.write_text(json.dumps(m, allow_nan=True))


def _mutate_lines(p: Path, rnd, text: str, sep: str) -> None:
    lines = p.read_text().splitlines()
    op = rnd.choice(["field", "field", "truncate", "drop", "dup", "bytes"])
    k = rnd.randrange(len(lines))
    if op == "field":
        fields = lines[k].split(sep)
        fields[rnd.randrange(len(fields))] = text
        lines[k] = sep.join(fields)
    elif op == "truncate":
        data = p.read_bytes()
        p.write_bytes(data[:rnd.randrange(len(data))])
        return
    elif op == "drop":
        del lines[k]
    elif op == "dup":
        lines.insert(k, lines[k])
    else:
        data = bytearray(p.read_bytes())
        data[rnd.randrange(len(data))] = rnd.randrange(256)
        p.write_bytes(bytes(data))
        return
    p.write_text("\n".join(lines) + "\n")


_DICOM_TAGS = ["ImagePositionPatient", "ImageOrientationPatient", "PixelSpacing", "Rows",
               "Columns", "TriggerTime", "InstanceNumber", "SliceThickness", "PatientID",
               "SOPInstanceUID", "HeartRate", "NominalInterval", "SeriesInstanceUID"]


def _mutate_dicom(study: Path, rnd, text: str) -> None:
    f = rnd.choice(sorted((study / "dicom").glob("*.dcm")))
    if rnd.random() < 0.2:
        data = f.read_bytes()
        f.write_bytes(data[:rnd.randrange(len(data))])
        return
    ds = pydicom.dcmread(f)
    tag = rnd.choice(_DICOM_TAGS)
    try:
        if rnd.random() < 0.2:
            delattr(ds, tag)
        else:
            value = rnd.choice([text, "\\".join([text] * 3), str(rnd.uniform(-1e3, 1e3)),
                                "1e-320", "nan", "-60", "0"])
            setattr(ds, tag, value)
        ds.save_as(f)
    except Exception:  # noqa: BLE001 - pydicom refused to write that value: nothing to test
        pass


def _apply(kind: str, study: Path, rnd, value, text) -> None:
    if kind == "study.json":
        _mutate_json(study, rnd, value)
    elif kind == "points.csv":
        _mutate_lines(study / "points.csv", rnd, text, ",")
    elif kind == "sunnybrook":
        files = sorted(study.rglob("*contour-manual.txt"))
        _mutate_lines(rnd.choice(files), rnd, text, " ")
    elif kind == "gpfile":
        files = sorted(study.glob("GPFile_*.txt")) + [study / "SliceInfoFile.txt"]
        _mutate_lines(rnd.choice(files), rnd, text, "\t")
    else:
        _mutate_dicom(study, rnd, text)


BASE_OF = {"study.json": "native", "points.csv": "native", "sunnybrook": "sunnybrook",
           "gpfile": "gpfile", "dicom": "sunnybrook"}


@seed(20261129)
@settings(max_examples=60, deadline=None, derandomize=False, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(m=mutations(), value=JSON_VALUES, text=TEXT)
def test_mutated_inputs_exit_0_or_2_and_open_nothing_outside(bases, tmp_path_factory, m, value,
                                                              text, capsys):
    kind, rnd = m
    work = tmp_path_factory.mktemp("fuzz")
    study = Path(shutil.copytree(bases[BASE_OF[kind]], work / "study"))
    _apply(kind, study, rnd, value, text)
    _WATCH["opened"] = []
    _WATCH["on"] = True
    try:
        load_study(study)
        loaded = True
    except CardioNurbsError as exc:
        loaded = False
        assert "\n" not in str(exc)
    finally:
        _WATCH["on"] = False
    assert _corpus().outside_opens(study, _WATCH["opened"]) == []
    if loaded and BASE_OF[kind] != "sunnybrook":
        return
    out = work / "out"
    capsys.readouterr()
    code = main(["analyze", str(study), "--out", str(out), "--no-figures"])
    err = capsys.readouterr().err
    assert code in (0, 2), err
    assert "Traceback" not in err
    if code == 2:
        assert err.count("\n") == 1 and err.startswith("cardionurbs: error: ")
        assert not out.exists() and [p.name for p in work.iterdir()] == ["study"]


# ------------------------------------------- the corpus of benchmarks/fuzz_inputs.py, sampled
@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    mod = _corpus()
    return mod, mod.make_bases(tmp_path_factory.mktemp("corpus_bases"))


def test_the_corpus_has_500_cases_across_the_five_kinds():
    mod = _corpus()
    all_cases = mod.cases(500, seed=31)
    assert len(all_cases) == 500 and {c.kind for c in all_cases} == set(mod.KINDS)


@pytest.mark.parametrize("index", range(0, 500, 33))
def test_a_sample_of_the_corpus_keeps_the_exit_contract(corpus, tmp_path, index):
    """15 of the 500 cases (every kind): a study or one CardioNurbsError line, analyze exit
    0 or 2 with one line, nothing opened outside the study, nothing written outside --out,
    no process left (the whole corpus: benchmarks/fuzz_inputs.py, reports/limits.md)."""
    mod, bases = corpus
    case = mod.cases(500, seed=31)[index]
    record = mod.run_case(case, bases, tmp_path)
    assert record["problems"] == [], record
