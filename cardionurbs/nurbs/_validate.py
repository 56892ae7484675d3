"""Input checks shared by the NURBS routines; every failure is a one-line
:class:`~cardionurbs.errors.NurbsInputError` naming the argument."""

from __future__ import annotations

import numpy as np

from cardionurbs.errors import NurbsInputError


def finite_array(value: object, name: str, ndim: int | None = None,
                 last_dim: int | None = None) -> np.ndarray:
    """``value`` as a float array; checks dimensionality and finiteness."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise NurbsInputError(f"{name}: not a numeric array ({exc})") from None
    if ndim is not None and arr.ndim != ndim:
        raise NurbsInputError(f"{name}: expected a {ndim}-d array, got shape {arr.shape}")
    if last_dim is not None and arr.shape[-1] != last_dim:
        raise NurbsInputError(f"{name}: expected last dimension {last_dim}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise NurbsInputError(f"{name}: contains {bad} NaN or infinite value(s)")
    return arr


def point_rows(value: object, name: str, dim: int) -> np.ndarray:
    """Query points as an (m, dim) array; a single point (dim,) is one row (1, dim)."""
    arr = finite_array(value, name)
    if arr.ndim == 1 and arr.shape[0] == dim:
        return arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise NurbsInputError(f"{name}: expected one point ({dim},) or points (m, {dim}), "
                              f"got shape {arr.shape}")
    return arr


def degree_value(value: object, name: str = "degree", minimum: int = 1) -> int:
    """A positive integer degree."""
    try:
        p = int(value)  # type: ignore[call-overload]
    except (TypeError, ValueError):
        raise NurbsInputError(f"{name}: must be an integer, got {value!r}") from None
    if p != value or p < minimum:
        raise NurbsInputError(f"{name}: must be an integer >= {minimum}, got {value!r}")
    return p


def knot_vector(value: object, name: str, degree: int, n_ctrl: int, clamped: bool) -> np.ndarray:
    """Checks a knot vector for ``n_ctrl`` control points of ``degree``."""
    U = finite_array(value, name, ndim=1)
    p = degree
    if U.size != n_ctrl + p + 1:
        raise NurbsInputError(f"{name}: needs {n_ctrl + p + 1} knots for {n_ctrl} control points "
                              f"of degree {p}, got {U.size}")
    if np.any(np.diff(U) < 0):
        raise NurbsInputError(f"{name}: knots must be non-decreasing")
    if not U[p] < U[n_ctrl]:
        raise NurbsInputError(f"{name}: empty parameter domain [{U[p]}, {U[n_ctrl]}]")
    if clamped:
        if np.any(U[:p + 1] != U[0]) or np.any(U[-p - 1:] != U[-1]):
            raise NurbsInputError(f"{name}: an open curve needs a clamped knot vector "
                                  f"(first and last knot repeated {p + 1} times)")
        inner = U[p + 1:n_ctrl]
    else:
        inner = U[p + 1:n_ctrl + p]
    if inner.size:
        _, counts = np.unique(inner, return_counts=True)
        if counts.max() > p:
            raise NurbsInputError(f"{name}: an interior knot has multiplicity {counts.max()} > degree {p}")
    return U


def periodic_knot_vector(value: object, name: str, degree: int, n_ctrl: int, what: str) -> np.ndarray:
    """Checks the periodic knot vector (n_ctrl + 2p + 1,) of ``n_ctrl`` distinct control points
    of ``degree`` wrapped around: domain [U[p], U[n_ctrl + p]] = [0, 1] and U[i + n_ctrl] =
    U[i] + 1 (``what`` names the closed object in the message, e.g. "a closed curve")."""
    p, n = degree, n_ctrl
    U = knot_vector(value, name, p, n + p, clamped=False)
    if abs(U[p]) > 1e-12 or abs(U[n + p] - 1.0) > 1e-12:
        raise NurbsInputError(f"{name}: {what} needs the domain [U[p], U[n+p]] = [0, 1], got "
                              f"[{U[p]}, {U[n + p]}]")
    if np.max(np.abs(U[n:] - U[:2 * p + 1] - 1.0)) > 1e-9:
        raise NurbsInputError(f"{name}: {what} needs a periodic knot vector (U[i + n] = U[i] + 1, "
                              f"n = {n})")
    return U


def weight_vector(value: object, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """Positive finite weights of the given shape (``None`` -> ones)."""
    if value is None:
        return np.ones(shape)
    w = finite_array(value, name)
    if w.shape != shape:
        raise NurbsInputError(f"{name}: expected shape {shape}, got {w.shape}")
    if np.any(w <= 0):
        raise NurbsInputError(f"{name}: weights must be > 0, got minimum {w.min()}")
    return w


def parameters(value: object, name: str, lo: float, hi: float, periodic: bool) -> np.ndarray:
    """A 1-d array of parameters in the domain [lo, hi]; wrapped when periodic."""
    u = finite_array(value, name)
    scalar = u.ndim == 0
    u = np.atleast_1d(u)
    if u.ndim != 1:
        raise NurbsInputError(f"{name}: expected a 1-d array of parameters, got shape {u.shape}")
    if periodic:
        period = hi - lo
        w = lo + np.mod(u - lo, period)
        # keep the end of the domain where the caller asked for it
        w[(u == hi)] = hi
        u = w
    else:
        slack = 1e-9 * (hi - lo)
        if u.size and (u.min() < lo - slack or u.max() > hi + slack):
            raise NurbsInputError(f"{name}: parameters must lie in [{lo}, {hi}], got "
                                  f"[{u.min()}, {u.max()}]")
        u = np.clip(u, lo, hi)
    return u[0:1] if scalar else u
