"""The ``cardionurbs`` command line.

Exit codes: 0 ok; 2 bad input or usage (one line on stderr, no traceback);
1 an internal error (one line on stderr; ``CARDIONURBS_DEBUG=1`` shows the
traceback).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Sequence

from cardionurbs.errors import CardioNurbsError, UsageError


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors as one line and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UsageError(f"{self.prog}: {message}")


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {v}")
    return v


def _nonneg_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (v >= 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return v


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


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="cardionurbs", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version="cardionurbs 0.1.0")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    ph = sub.add_parser("phantom", help="generate a phantom study (or a cohort of them)")
    ph.add_argument("--pathology", choices=["normal", "mr", "phtn"])
    ph.add_argument("--cohort", metavar="SPEC.toml", help="a cohort spec (phantoms/*.toml)")
    ph.add_argument("--seed", type=_nonneg_int, default=0)
    ph.add_argument("--frames", type=_positive_int, default=20)
    ph.add_argument("--noise-px", type=_nonneg_float, default=0.0,
                    help="contour and tag noise, pixels (standard deviation)")
    ph.add_argument("--tag-jumps", type=_nonneg_int, default=0,
                    help="number of (slice, frame) pairs with a tag-jumping fault")
    ph.add_argument("--breath-hold-mm", type=_nonneg_float, default=0.0,
                    help="breath-hold fault: random in-plane shifts of the SA slices, mm (std)")
    ph.add_argument("--snr", type=_positive_float, default=None,
                    help="tagged DICOM image SNR (myocardium over Rician channel noise; default 12)")
    ph.add_argument("--no-dicom", action="store_true", help="skip the synthetic DICOM images")
    ph.add_argument("--out", required=True, metavar="DIR")

    an = sub.add_parser("analyze", help="reconstruct and measure one study")
    an.add_argument("study", metavar="STUDY")
    an.add_argument("--format", default="auto", choices=["auto", "native", "sunnybrook", "gpfile"])
    an.add_argument("--heart-rate", type=float, default=None, help="bpm, when the input has none")
    an.add_argument("--no-figures", action="store_true", help="skip PNG figures and HTML report")
    an.add_argument("--out", required=True, metavar="DIR")

    co = sub.add_parser("cohort", help="measure many studies into one CSV")
    co.add_argument("studies", nargs="+", metavar="STUDY")
    co.add_argument("--csv", required=True, metavar="FILE")
    co.add_argument("--jobs", type=_positive_int, default=1)
    co.add_argument("--format", default="auto", choices=["auto", "native", "sunnybrook", "gpfile"])
    co.add_argument("--strict", action="store_true",
                    help="a study whose metrics carry a quality flag (QC) is a failure")

    de = sub.add_parser("demo", help="the paper's 12-subject phantom cohort, end to end")
    de.add_argument("--out", metavar="DIR", default=None)
    de.add_argument("--jobs", type=_positive_int, default=None,
                    help="worker processes (default: one per CPU core)")

    rp = sub.add_parser("report", help="self-contained offline HTML viewer of an analysis folder")
    rp.add_argument("output_dir", metavar="OUTPUT_DIR")
    rp.add_argument("--out", required=True, metavar="report.html")
    return p


def _run(args: argparse.Namespace) -> int:
    if args.command == "phantom":
        from cardionurbs.phantom.cli import run_phantom
        return run_phantom(args)
    if args.command == "analyze":
        from cardionurbs.pipeline import run_analyze
        return run_analyze(args)
    if args.command == "cohort":
        from cardionurbs.cohort import run_cohort
        return run_cohort(args)
    if args.command == "demo":
        from cardionurbs.demo import run_demo
        return run_demo(args)
    if args.command == "report":
        from cardionurbs.report.html import run_report
        return run_report(args)
    raise UsageError("cardionurbs: a command is required (phantom, analyze, cohort, demo, report)")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``cardionurbs`` console script."""
    try:
        args = build_parser().parse_args(argv)
        return int(_run(args) or 0)
    except CardioNurbsError as exc:
        print(f"cardionurbs: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError) as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"cardionurbs: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cardionurbs: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the CLI never shows a traceback
        if os.environ.get("CARDIONURBS_DEBUG"):
            raise
        print(f"cardionurbs: internal error: {type(exc).__name__}: {_one_line(exc)}",
              file=sys.stderr)
        return 1


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
