"""The ``cardionurbs`` command line.

Exit codes, always:

* 0 -- done;
* 2 -- bad input or usage: one line on stderr, ``cardionurbs: error: ...``, naming the
  argument, file, slice, frame or field at fault; nothing written;
* 1 -- internal error: one line on stderr and the path of a file holding the full
  traceback (``--debug`` or ``CARDIONURBS_DEBUG=1`` prints it instead);
* 3 -- ``cohort`` finished but some study failed (each in its row; the summary line
  on stderr counts them); ``--allow-failures`` gives 0 instead;
* 130 -- interrupted (Ctrl-C, SIGINT); 143 -- terminated (SIGTERM). Outputs are
  written atomically, so an interrupted run leaves the previous output intact.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from typing import Sequence

from cardionurbs.errors import CardioNurbsError, UsageError
from cardionurbs.limits import HEART_RATE_RANGE_BPM, MAX_FRAMES
from cardionurbs.safe import excerpt, printable


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors as one line and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        cmd = self.prog.split(" ", 1)[1] if " " in self.prog else ""
        raise UsageError(f"{cmd}: {message}" if cmd else message)


def _excerpt(text: object, n: int = 40) -> str:
    """A short printable quotation of user input (at most ``n`` characters)."""
    return excerpt(text, n)


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return v


def _nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {v}")
    return v


def _pathology(text: str) -> str:
    """A stated pathology: 1-64 letters, digits, spaces, '-' or '_' (e.g. ``mr``)."""
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9 _-]{0,63}", text):
        raise argparse.ArgumentTypeError(f"expected a pathology name (letters, digits, spaces, "
                                         f"'-', '_'; at most 64), got {_excerpt(text)}")
    return text


def _heart_rate(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of beats per minute, got "
                                         f"{_excerpt(text)}") from None
    if not (HEART_RATE_RANGE_BPM[0] <= v <= HEART_RATE_RANGE_BPM[1]):
        raise argparse.ArgumentTypeError(
            f"must be between {HEART_RATE_RANGE_BPM[0]:g} and {HEART_RATE_RANGE_BPM[1]:g} bpm, "
            f"got {_excerpt(text)}")
    return v


def _uncertainty_options(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``--uncertainty on|off`` of analyze and cohort, ``--max-halfwidth`` of cohort (added to
    the parser :func:`build_parser` made; returns it)."""
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    for name in ("analyze", "cohort"):
        sub.choices[name].add_argument(
            "--uncertainty", choices=("on", "off"), default="on",
            help="95 %% intervals of the global metrics (docs/metrics.md, Uncertainty)")
    sub.choices["cohort"].add_argument(
        "--max-halfwidth", type=_max_halfwidth, default=None, metavar="METRIC=LIMIT[,...]",
        help="flag (QC) a study whose 95 %% interval of METRIC is wider than ± LIMIT "
             "(its unit), e.g. LVEF=5,LVEDV=10")
    return p


def _max_halfwidth(text: str) -> dict:
    from cardionurbs.analysis.uncertainty import parse_max_halfwidth
    try:
        return parse_max_halfwidth(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _study_input_options(parser: argparse.ArgumentParser, format_help: str) -> None:
    """--format and --labels, as analyze and cohort take them."""
    parser.add_argument("--format", default="auto",
                        choices=["auto", "native", "sunnybrook", "gpfile", "nifti"],
                        help=format_help)
    parser.add_argument("--labels", default=None, metavar="PRESET|MAPPING",
                        help="label-map convention: acdc, ukbb, mnms, bivme or lv=N,myo=N,rv=N "
                             "(default: the layout's, or inferred from topology)")


def _output_safety_options(parser: argparse.ArgumentParser) -> None:
    """--overwrite and --allow-outside, as analyze and track take them."""
    parser.add_argument("--overwrite", action="store_true",
                        help="replace --out when it holds an earlier cardionurbs output")
    parser.add_argument("--allow-outside", action="store_true",
                        help="let study.json name files outside the study folder")


def _bounded(kind, lo, hi, unit=""):
    """An argparse type: a number of ``kind`` in [lo, hi]."""
    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {'whole ' if kind is int else ''}number, "
                                             f"got {_excerpt(text)}") from None
        if not (lo <= v <= hi):
            raise argparse.ArgumentTypeError(f"must be between {lo:g} and {hi:g}{unit}, got "
                                             f"{_excerpt(text)}")
        return v
    parse.__name__ = kind.__name__
    return parse


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Help with every option's default (argparse's ArgumentDefaultsHelpFormatter), said
    once: nothing is added for required options, options without a default (None), on/off
    flags (``store_true``: off unless given) and help that states its default itself."""

    def _get_help_string(self, action):
        flag = isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction))
        if action.required or action.default is None or action.help is None or flag \
                or "default" in action.help:
            return action.help
        return super()._get_help_string(action)



DESCRIPTION = """NURBS models of the left and right ventricle from cardiac MR contours and
tag lines: reconstruct and measure studies, generate phantoms with known ground truth,
and build reports. Exit codes: 0 done; 2 bad input or usage (one line on stderr);
1 internal error (one line and the file holding the traceback); 3 cohort done but
some study failed; 130 interrupted (Ctrl-C), 143 terminated (SIGTERM)."""


def _analyze_output_options(parser: argparse.ArgumentParser) -> None:
    """``analyze --mesh-format`` (docs/outputs.md) and ``--progress``."""
    parser.add_argument("--mesh-format", choices=["ply", "stl", "obj", "glb", "vtp"], default="ply",
                        help="mesh files: vtp is VTK PolyData with wall thickness, AHA segments "
                             "and strain on the surfaces, and a ParaView .pvd time series per mesh")
    parser.add_argument("--progress", action="store_true",
                        help="stage progress on stderr (default: only when stderr is a terminal)")


def build_parser() -> argparse.ArgumentParser:
    """The ``cardionurbs`` argument parser, every subcommand and option (docs/usage.md).

    Returns
    -------
    argparse.ArgumentParser
        Usage errors leave it as one line and exit code 2.
    """
    p = _Parser(prog="cardionurbs", description=DESCRIPTION, formatter_class=_HelpFormatter)
    p.add_argument("--version", action="version", version="cardionurbs 0.1.0")
    p.add_argument("--debug", action="store_true",
                   help="on an internal error, print the full traceback")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    def command(name, help):
        return sub.add_parser(name, help=help, description=help, formatter_class=_HelpFormatter)

    for add in (_phantom_command, _analyze_command, _track_command, _cohort_command,
                _demo_report_commands):
        add(command)
    return _uncertainty_options(p)


def _phantom_command(command) -> None:
    """Add the ``phantom`` command's options (``command(name, help)`` makes a subparser)."""
    ph = command("phantom", "generate a phantom study (or a cohort of them)")
    ph.add_argument("--pathology", choices=["normal", "mr", "phtn"],
                    help="the preset to generate (or use --cohort)")
    ph.add_argument("--cohort", metavar="SPEC.toml", help="a cohort spec (phantoms/*.toml)")
    ph.add_argument("--seed", type=_nonneg_int, default=0, help="random seed")
    ph.add_argument("--frames", type=_bounded(int, 1, MAX_FRAMES), default=20,
                    help="cardiac phases over one cycle")
    ph.add_argument("--noise-px", type=_bounded(float, 0.0, 100.0, " px"), default=0.0,
                    help="contour and tag noise, pixels (standard deviation)")
    ph.add_argument("--tag-jumps", type=_bounded(int, 0, 10_000), default=0,
                    help="number of (slice, frame) pairs with a tag-jumping fault")
    ph.add_argument("--breath-hold-mm", type=_bounded(float, 0.0, 100.0, " mm"), default=0.0,
                    help="breath-hold fault: random in-plane shifts of the SA slices, mm (std)")
    ph.add_argument("--snr", type=_positive_float, default=None,
                    help="tagged DICOM image SNR (myocardium over Rician channel noise; default 12)")
    ph.add_argument("--anatomy", choices=["ideal", "realistic"], default="ideal",
                    help="ideal spheroids (default) or realistic hearts: shape modes, segmental "
                         "wall thickness, varying RV crescent, saddle mitral and tricuspid annuli, "
                         "apex off the long axis, outflow tracts (docs/phantoms.md)")
    ph.add_argument("--infarct", choices=["lad", "rca", "lcx"], default=None,
                    help="make this coronary territory thinner and hypokinetic (border zone "
                         "included)")
    ph.add_argument("--outflow", action=argparse.BooleanOptionalAction, default=None,
                    help="the RV outflow tract to a pulmonary valve and the LV outflow tract to "
                         "an aortic valve (RVOT view, rv_outlet SA contours, pulmonary/aortic "
                         "landmarks): on by default with --anatomy realistic, --no-outflow leaves "
                         "them out; the ideal anatomy has none")
    ph.add_argument("--realism", choices=["clinical"], default=None,
                    help="clinical acquisition faults at once: 0.5 px contour noise, 1.5 mm "
                         "breath-hold shifts, image SNR 15 (unless given); truth unchanged")
    ph.add_argument("--no-dicom", action="store_true", help="skip the synthetic DICOM images")
    ph.add_argument("--n", type=_bounded(int, 1, 10_000_000), default=None, metavar="N",
                    help="with --cohort: N subjects from the spec's mix (subject k takes "
                         "spec subject k mod m, with its own seed), generated in parallel")
    ph.add_argument("--jobs", type=_bounded(int, 1, 1024), default=1,
                    help="with --n: worker processes (or Dask workers with --dask local)")
    ph.add_argument("--dask", metavar="local|tcp://HOST:PORT", default=None,
                    help="with --n: generate on Dask (a LocalCluster, or an existing scheduler)")
    ph.add_argument("--resume", action="store_true",
                    help="with --n: keep the subjects an earlier run of the same --out finished")
    ph.add_argument("--labels", choices=["acdc", "ukbb", "mnms", "mnms2"], default=None,
                    help="also write NIfTI label maps (and a cine-like image) in this "
                         "convention and layout, in DIR/labelmaps")
    ph.add_argument("--label-quirks", default=None, metavar="LIST",
                    help="with --labels: header quirks, comma-separated: real (the dataset's "
                         "own header: ACDC unit-scale sform + pixdim spacing, base first; UK "
                         "Biobank frame interval in s with unknown unit), lps (in-plane axes "
                         "stored reversed), apex-first, base-first, pv (partial-volume labels); "
                         "docs/formats.md")
    ph.add_argument("--sa-spacing", type=_bounded(float, 1.0, 30.0), default=None, metavar="MM",
                    help="distance between SA slices (default 10 mm)")
    ph.add_argument("--sa-thickness", type=_bounded(float, 1.0, 30.0), default=None, metavar="MM",
                    help="SA slice thickness (default 8 mm; less than --sa-spacing leaves gaps)")
    ph.add_argument("--out", required=True, metavar="DIR",
                    help="new (or empty) output folder")
    ph.add_argument("--overwrite", action="store_true",
                    help="replace --out when it holds an earlier cardionurbs output")


def _analyze_command(command) -> None:
    """Add the ``analyze`` command's options (``command(name, help)`` makes a subparser)."""
    an = command("analyze", "reconstruct and measure one study")
    an.add_argument("study", metavar="STUDY",
                    help="study folder (or its study.json), or a NIfTI label map")
    _study_input_options(an, "input format")
    an.add_argument("--heart-rate", type=_heart_rate, default=None, metavar="BPM",
                    help="bpm (20-300), when the input has none")
    for which in ("ED", "ES"):
        an.add_argument(f"--{which.lower()}-frame", type=_bounded(int, 0, 9999), default=None,
                        metavar="N", help=f"{which} frame index (0-based) of a NIfTI label-map "
                                          "study, used as given (for layouts that do not say)")
    an.add_argument("--pathology", type=_pathology, default=None, metavar="TEXT",
                    help="the study's stated pathology (e.g. mr): makes MR RegVol / RegFrac "
                         "answer a stated question; without it (or the study's own metadata) "
                         "LVSV-RVSV is reported instead (docs/metrics.md)")
    an.add_argument("--no-figures", action="store_true", help="skip PNG figures and HTML report")
    an.add_argument("--outputs", default="all", metavar="LIST",
                    help="comma-separated subset of metrics,model,meshes,figures,report "
                         "(report also writes metrics and model)")
    _analyze_output_options(an)
    an.add_argument("--jobs", type=_bounded(int, 1, 1024), default=None, metavar="N",
                    help="processes for the per-frame work (meshes, tag strain over time; "
                         "default: the CPUs this process may use; 1: one process)")
    an.add_argument("--out", required=True, metavar="DIR",
                    help="new (or empty) output folder, outside the study")
    _output_safety_options(an)
    an.add_argument("--track-tags", action="store_true",
                    help="track the tag lines from the study's tagged DICOM (HARP) first")
    an.add_argument("--height-cm", type=_bounded(float, 30.0, 250.0, " cm"), default=None,
                    metavar="H", help="body height (cm) for BSA and the indexed columns "
                                      "(replaces the study's)")
    an.add_argument("--weight-kg", type=_bounded(float, 1.0, 400.0, " kg"), default=None,
                    metavar="W", help="body weight (kg; replaces the study's)")
    an.add_argument("--age", type=_bounded(float, 0.0, 120.0, " years"), default=None,
                    metavar="YEARS", help="age for the reference ranges (replaces the study's)")
    an.add_argument("--sex", choices=["F", "M"], default=None,
                    help="sex for the reference ranges (replaces the study's)")
    an.add_argument("--verbose", action="store_true",
                    help="print every warning on stderr, not only the count and the first few")


def _track_command(command) -> None:
    """Add the ``track`` command's options (``command(name, help)`` makes a subparser)."""
    tr = command("track", "track tag lines from a study's tagged DICOM images (HARP)")
    tr.add_argument("study", metavar="STUDY", help="native study folder whose images name DICOM files")
    tr.add_argument("--out", required=True, metavar="DIR",
                    help="new (or empty) output folder, outside the study")
    tr.add_argument("--label-maps", default=None, metavar="PATH",
                    help="NIfTI label maps of the tagged images (a file or an ACDC / UK Biobank "
                         "/ M&Ms folder): clip the lines to their myocardium pixels")
    _output_safety_options(tr)


def _cohort_command(command) -> None:
    """Add the ``cohort`` command's options (``command(name, help)`` makes a subparser)."""
    co = command("cohort", "measure many studies into one CSV")
    co.add_argument("studies", nargs="+", metavar="STUDY", help="study folders or label maps")
    co.add_argument("--csv", required=True, metavar="FILE",
                    help="output CSV (an earlier cohort table is replaced atomically; any "
                         "other existing file only with --overwrite)")
    co.add_argument("--overwrite", action="store_true",
                    help="let --csv / --parquet replace an existing file cardionurbs did not write")
    co.add_argument("--jobs", type=_bounded(int, 1, 1024), default=1,
                    help="worker processes (or Dask workers with --dask local)")
    co.add_argument("--dask", metavar="local|tcp://HOST:PORT", default=None,
                    help="run on Dask: a LocalCluster on 127.0.0.1, or an existing scheduler")
    co.add_argument("--timeout", type=_positive_float, default=None, metavar="S",
                    help="seconds per study; a study still running then becomes an error row")
    co.add_argument("--run-dir", default=None, metavar="DIR",
                    help="where finished rows are kept (default: the CSV path + '.rows')")
    co.add_argument("--resume", action="store_true",
                    help="keep the rows a previous run of the same studies finished")
    co.add_argument("--parquet", action="store_true", help="also write the table as .parquet")
    co.add_argument("--allow-failures", action="store_true",
                    help="exit 0 even when some study failed (default: exit 3)")
    _study_input_options(co, "input format of every study")
    co.add_argument("--allow-outside", action="store_true",
                    help="let study.json name files outside the study folder")
    co.add_argument("--strict", action="store_true",
                    help="a study whose metrics carry a quality flag (QC) is a failure")


def _demo_report_commands(command) -> None:
    """Add the ``demo`` and ``report`` commands' options (``command(name, help)`` makes a subparser)."""
    de = command("demo", "the paper's 12-subject phantom cohort, end to end")
    de.add_argument("--out", metavar="DIR", default=None,
                    help="new (or empty) output folder; default: a temporary folder, "
                         "removed at the end unless --keep")
    de.add_argument("--overwrite", action="store_true",
                    help="replace --out when it holds an earlier cardionurbs output")
    de.add_argument("--keep", action="store_true",
                    help="keep the temporary folder (when no --out is given)")
    de.add_argument("--jobs", type=_bounded(int, 1, 1024), default=None,
                    help="worker processes (default: one per CPU core)")

    rp = command("report", "self-contained offline HTML viewer of an analysis folder")
    rp.add_argument("output_dir", metavar="OUTPUT_DIR", help="a folder written by analyze")
    rp.add_argument("--out", required=True, metavar="report.html",
                    help="the HTML file to write (replaced atomically when it exists)")


def _run(args: argparse.Namespace) -> int:
    if args.command == "phantom":
        from cardionurbs.phantom.cli import run_phantom
        return run_phantom(args)
    if args.command == "analyze":
        from cardionurbs.pipeline import run_analyze
        return run_analyze(args)
    if args.command == "track":
        from cardionurbs.tracking.track import run_track
        return run_track(args)
    if args.command == "cohort":
        from cardionurbs.cohort import run_cohort
        return run_cohort(args)
    if args.command == "demo":
        from cardionurbs.demo import run_demo
        return run_demo(args)
    if args.command == "report":
        from cardionurbs.report.html import run_report
        return run_report(args)
    raise UsageError("a command is required (phantom, analyze, track, cohort, demo, report)")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread so that cleanup (atomic outputs) runs.

    Parameters
    ----------
    signum : int
        The signal number (15).
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum, frame):  # noqa: ARG001 - signal handler signature
    raise Terminated(signum)


def _install_signal_handlers() -> None:
    import signal
    import threading
    if threading.current_thread() is not threading.main_thread():
        return
    signal.signal(signal.SIGTERM, _raise_terminated)
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:  # e.g. started with nohup &
        return
    signal.signal(signal.SIGINT, signal.default_int_handler)


def _write_traceback(exc: BaseException, argv) -> str:
    """Write the full traceback of an internal error to a file; return its path."""
    import tempfile
    import traceback
    fd, path = tempfile.mkstemp(prefix="cardionurbs-traceback-", suffix=".txt")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(f"cardionurbs {' '.join(map(str, argv))}\n\n")
        f.write("".join(traceback.format_exception(type(exc), exc, exc.__traceback__)))
    return path


#: the thread-count variables of the BLAS libraries numpy and scipy may load
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> bool:
    """Run numpy's BLAS on one thread in this process and the workers it starts, unless
    the user set any of :data:`BLAS_THREAD_VARIABLES` or numpy is already loaded (the
    library reads them once, when it loads). True when the limit was set.

    The analysis multiplies small matrices (control grids of tens to hundreds of
    points) thousands of times; OpenBLAS's default of one thread per core spends more
    CPU waking and spinning its threads than it saves: a metrics-only ``analyze`` of a
    20-frame phantom took about 60 % more CPU time with the default threads than with
    one (reports/benchmark-throughput.md), and a cohort runs one worker per core anyway.

    Returns
    -------
    bool
        True when the limit was set.
    """
    if "numpy" in sys.modules or any(v in os.environ for v in BLAS_THREAD_VARIABLES):
        return False
    for v in BLAS_THREAD_VARIABLES:
        os.environ[v] = "1"
    return True


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``cardionurbs`` console script (exit codes: module docstring).

    Parameters
    ----------
    argv : sequence of str or None
        The arguments after the program name; None: ``sys.argv[1:]``.

    Returns
    -------
    int
        The exit code (0, 1, 2, 3, 130 or 143: the module docstring says when).
    """
    one_blas_thread()
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv[:argv.index("--")] if "--" in argv else "--debug" in argv
    debug = debug or bool(os.environ.get("CARDIONURBS_DEBUG"))
    argv = [a for a in argv if a != "--debug"] if debug else argv
    from cardionurbs.safe import quiet_third_party
    quiet_third_party(show=debug)
    try:
        _install_signal_handlers()
        args = build_parser().parse_args(argv)
        return int(_run(args) or 0)
    except Terminated as exc:
        print("cardionurbs: terminated", file=sys.stderr)
        return 128 + exc.signum
    except KeyboardInterrupt:
        print("cardionurbs: interrupted", file=sys.stderr)
        return 130
    except CardioNurbsError as exc:
        print(f"cardionurbs: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError,
            FileExistsError) as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"cardionurbs: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - the CLI never shows a traceback unasked
        if debug:
            import traceback
            traceback.print_exc()
            return 1
        try:
            where = f"; traceback in {_write_traceback(exc, argv)}"
        except OSError:
            where = "; rerun with --debug for the traceback"
        print(f"cardionurbs: internal error: {type(exc).__name__}: {_one_line(exc)}{where}",
              file=sys.stderr)
        return 1


def _one_line(exc: BaseException) -> str:
    text = printable(" ".join(str(exc).split()))
    text = text.removeprefix("cardionurbs: error: ").removeprefix("cardionurbs: ")
    if len(text) > 2000:
        text = text[:2000] + f"... ({len(text)} characters)"
    return text or type(exc).__name__


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
