"""Stage progress of a long command on stderr: ``analyze: reconstruct 7/20`` and timings.

Shown when stderr is a terminal (or when asked, ``--progress``); silent otherwise, so
pipes and cohort workers stay quiet. On a terminal counted stages rewrite one line
(carriage return); elsewhere every stage ends with one line ``<prefix>: <stage> done
(<s> s)``.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """Report stages (``stage(name)``) and counted steps (``step(k, n)``) of one command.

    Parameters
    ----------
    enabled : bool or None, optional
        Write stage lines at all; ``None`` (default): only when ``stream`` is a terminal.
    prefix : str, optional
        Text before every line, usually the command name (``"cardionurbs"``).
    stream : text stream or None, optional
        Where the lines go; ``None`` (default): :data:`sys.stderr`.

    Attributes
    ----------
    timings : dict of str to float
        Wall time of every ended stage, in s (repeated stages summed).
    """

    def __init__(self, enabled: bool | None = None, prefix: str = "cardionurbs",
                 stream: TextIO | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.enabled = self.tty if enabled is None else bool(enabled)
        self.prefix = prefix
        self._name: str | None = None
        self._t0 = 0.0
        self.timings: dict[str, float] = {}

    def stage(self, name: str) -> "Progress":
        """Start stage ``name`` (ends the previous one).

        Parameters
        ----------
        name : str
            The stage's name as shown (``"reconstruct"``) and as keyed in :attr:`timings`.

        Returns
        -------
        Progress
            ``self``, so that ``progress.stage("x")`` can be chained.
        """
        self.done()
        self._name, self._t0 = name, time.perf_counter()
        if self.enabled and self.tty:
            self._write(f"\r{self.prefix}: {name} ...\x1b[K")
        return self

    def step(self, k: int, n: int) -> None:
        """Step k of n of the current stage done (rewrites the line on a terminal).

        Parameters
        ----------
        k : int
            Steps done so far (1-based: ``k`` of ``n``).
        n : int
            Steps the stage has in all.
        """
        if self.enabled and self.tty:
            self._write(f"\r{self.prefix}: {self._name} {k}/{n}\x1b[K")

    def done(self) -> None:
        """End the current stage (records its wall time in :attr:`timings`)."""
        if self._name is None:
            return
        dt = time.perf_counter() - self._t0
        self.timings[self._name] = self.timings.get(self._name, 0.0) + dt
        if self.enabled:
            line = f"{self.prefix}: {self._name} done ({dt:.2f} s)"
            self._write("\r" + line + "\x1b[K\n" if self.tty else line + "\n")
        self._name = None

    def _write(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):      # a closed or broken stderr never stops the work
            self.enabled = False
