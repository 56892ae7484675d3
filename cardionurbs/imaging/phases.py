"""Cardiac phases of a cine series: frame indices from trigger times, heart rate.

A cine MR slice is acquired as ``N`` phases evenly spread over one R-R
interval (``CardiacNumberOfImages`` = N, ``NominalInterval`` = R-R in ms).
The DICOM ``TriggerTime`` (0018,1060) of phase ``k`` is about
``t_k = t_0 + k * RR / N`` with ``0 <= t_0 < RR / N``; slices acquired in
different breath-holds have slightly different R-R intervals, so trigger
times of one phase differ from slice to slice and frames cannot be matched
by equal trigger times across slices.

:func:`phase_indices` therefore numbers the images of ONE slice: by rank of
trigger time when the slice holds all ``N`` phases (or ``N`` is unknown), and
by ``floor(t * N / RR)`` when it holds only some of them (e.g. a contoured
subset of the series, as in the Sunnybrook data), so that a frame index means
the same cardiac phase in every slice.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from cardionurbs.errors import StudyError
from cardionurbs.limits import HEART_RATE_RANGE_BPM

#: fraction of a phase interval added before flooring t * N / RR, so that a
#: trigger time written with a few digits less than k * RR / N still gives k.
_PHASE_SLACK = 1e-3


def phase_indices(trigger_times_ms: Sequence[float], n_phases: int | None = None,
                  rr_ms: float | None = None, *, slice: object = None) -> np.ndarray:
    """Frame (phase) index of each image of one slice, from its trigger times (ms).

    Parameters
    ----------
    trigger_times_ms : sequence of float
        TriggerTime of every image of the slice (any order, all finite).
    n_phases : int, optional
        CardiacNumberOfImages N (phases per R-R interval).
    rr_ms : float, optional
        R-R interval, ms (NominalInterval, or 60000 / HeartRate).
    slice : object, optional
        The slice id, for the messages.

    Returns
    -------
    (n,) int ndarray
        With all N phases present (or N / RR unknown): the rank of each
        trigger time. Otherwise ``floor(t * N / RR + 1e-3)`` clipped to
        ``[0, N - 1]``. Indices of one slice are always distinct.

    Raises
    ------
    StudyError
        Two images of the slice share a phase (naming the slice).
    """
    t = np.asarray(trigger_times_ms, dtype=float).reshape(-1)
    if t.size == 0:
        return np.zeros(0, dtype=int)
    if not np.all(np.isfinite(t)):
        raise StudyError("trigger times must be finite numbers", slice=slice, field="TriggerTime")
    order = np.argsort(t, kind="stable")
    if np.any(np.diff(t[order]) == 0):
        dup = t[order][np.flatnonzero(np.diff(t[order]) == 0)[0]]
        raise StudyError(f"two images share TriggerTime {dup:g} ms (duplicate image?)",
                         slice=slice, field="TriggerTime")
    ranks = np.empty(t.size, dtype=int)
    ranks[order] = np.arange(t.size)
    if n_phases is None or rr_ms is None or not (rr_ms > 0) or n_phases < 1 or t.size >= n_phases:
        return ranks
    k = np.clip(np.floor(t * n_phases / rr_ms + _PHASE_SLACK), 0, n_phases - 1).astype(int)
    if np.unique(k).size != k.size:
        # timing inconsistent with N and RR: fall back to the order of acquisition
        return ranks
    return k


def rr_interval_ms(heart_rate_bpm: float | None = None,
                   nominal_interval_ms: float | None = None) -> float | None:
    """R-R interval in ms: NominalInterval when given, else 60000 / HeartRate.

    Parameters
    ----------
    heart_rate_bpm : float or None, optional
        HeartRate (0018,1088), in beats/min.
    nominal_interval_ms : float or None, optional
        NominalInterval (0018,1062), in ms.

    Returns
    -------
    float or None
        The R-R interval in ms; None when neither value is given and > 0.
    """
    if nominal_interval_ms is not None and nominal_interval_ms > 0:
        return float(nominal_interval_ms)
    if heart_rate_bpm is not None and heart_rate_bpm > 0:
        return 60000.0 / float(heart_rate_bpm)
    return None


def heart_rate_bpm(heart_rates: Sequence[float | None],
                   nominal_intervals_ms: Sequence[float | None] = ()) -> float | None:
    """Heart rate of a series (docs/metrics.md, Frames): the mean DICOM HeartRate (0018,1088)
    of its images; else 60000 / mean NominalInterval (0018,1062); else None.

    Zero or missing values (scanners write 0 when they do not know) are ignored, and so
    are implausible ones (outside 20-300 bpm, or a NominalInterval giving such a rate).

    Parameters
    ----------
    heart_rates : sequence of float or None
        HeartRate of every image, in beats/min (None where absent).
    nominal_intervals_ms : sequence of float or None, optional
        NominalInterval of every image, in ms (None where absent).

    Returns
    -------
    float or None
        The heart rate in beats/min, None when no plausible value is given.
    """
    lo, hi = HEART_RATE_RANGE_BPM
    hr = np.array([h for h in heart_rates if h is not None], dtype=float)
    hr = hr[np.isfinite(hr) & (hr >= lo) & (hr <= hi)]
    if hr.size:
        return float(hr.mean())
    ni = np.array([v for v in nominal_intervals_ms if v is not None], dtype=float)
    ni = ni[np.isfinite(ni) & (ni >= 60000.0 / hi) & (ni <= 60000.0 / lo)]
    if ni.size:
        return float(60000.0 / ni.mean())
    return None
