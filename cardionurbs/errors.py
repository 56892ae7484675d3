"""Exception types of cardionurbs.

Every error a user can cause with bad input is a subclass of
:class:`CardioNurbsError`, itself a :class:`ValueError`, and its message is
one line that names the argument, file, slice, frame or field at fault.
The CLI turns any of them into one line on stderr and exit code 2.
"""

from __future__ import annotations


class CardioNurbsError(ValueError):
    """Base class of every input error raised by cardionurbs."""


class NurbsInputError(CardioNurbsError):
    """Bad argument to a NURBS routine (names the argument and what is wrong)."""


class StudyError(CardioNurbsError):
    """Bad or inconsistent study input: DICOM, contours, tags, landmarks.

    The message is built from the parts that locate the fault, e.g.
    ``StudyError("contour has 3 points, needs >= 5", file="c.csv", slice="sa_03", frame=0)``
    gives ``c.csv: slice sa_03, frame 0: contour has 3 points, needs >= 5``.

    Parameters
    ----------
    message : str
        What is wrong (one line; whitespace runs are collapsed).
    file, slice, frame, field : object or None
        Where: the file, the slice id, the frame index and the field (column, tag or
        option) of the fault; each kept as an attribute of the same name.
    """

    def __init__(self, message: str, *, file: object = None, slice: object = None,
                 frame: object = None, field: object = None) -> None:
        self.file, self.slice, self.frame, self.field = file, slice, frame, field
        where = []
        if slice is not None:
            where.append(f"slice {slice}")
        if frame is not None:
            where.append(f"frame {frame}")
        if field is not None:
            where.append(f"field {field}")
        prefix = f"{file}: " if file is not None else ""
        if where:
            prefix += ", ".join(where) + ": "
        super().__init__(" ".join((prefix + str(message)).split()))


class UnsupportedInputError(StudyError):
    """Input that is valid but not supported (e.g. enhanced multi-frame MR)."""


class PhantomError(CardioNurbsError):
    """Bad phantom parameters or preset/cohort specification."""


class ReconstructionError(CardioNurbsError):
    """A surface or mesh could not be built (names structure and frame)."""


class TagError(StudyError):
    """Bad tag-line input (names family, index, slice and frame)."""


class TagTrackingError(TagError):
    """Tagged images that cannot be tracked: no SPAMM pattern (untagged or faded series), or
    a tag spacing or orientation far from what the study expects (names file, slice, frame)."""


class ExportError(CardioNurbsError):
    """Unsupported export format or unwritable output (names the path or format)."""


class UsageError(CardioNurbsError):
    """Bad command-line usage (the CLI prints it as one line, exit code 2)."""


class ReportInputError(CardioNurbsError):
    """The analysis folder given to ``report`` is missing or incomplete (names the file)."""


class CohortInputError(CardioNurbsError):
    """A cohort or truth table for the cohort figures is missing or malformed (names the file)."""


class ChromiumError(RuntimeError):
    """Chromium could not be started or did not answer (an environment problem, not bad
    input: hence a RuntimeError, not a :class:`CardioNurbsError`)."""


class OutputError(CardioNurbsError):
    """An output path that would destroy data (an input, a folder cardionurbs did not
    write, an existing file) or cannot be written; names the option (``--out``, ``--csv``).

    Parameters
    ----------
    message : str
        The one-line message.
    option : str or None
        The option it concerns (``--out``, ``--csv``, ...).
    """

    def __init__(self, message: str, *, option: str | None = None) -> None:
        self.option = option
        super().__init__(" ".join(str(message).split()))


class LimitError(StudyError):
    """Input past a documented limit (points per contour, contours, frames, name length)."""


class SegmentError(StudyError):
    """The AHA segments cannot be placed (e.g. no RV insertion points nor RV contours)."""


# ------------------------------------------- worker processes (not input errors: exit 1)
class WorkerDied(ChildProcessError):
    """A worker process (:mod:`cardionurbs.parallel`, :mod:`cardionurbs.workers`) ended
    without reporting its item: a signal, the out-of-memory killer, ``os._exit``."""


class RemoteTraceback(Exception):
    """The traceback of an exception raised in a worker process (the ``__cause__`` of the
    exception :func:`cardionurbs.parallel.fork_map` raises in the parent)."""

    def __str__(self) -> str:
        return self.args[0] if self.args else ""
