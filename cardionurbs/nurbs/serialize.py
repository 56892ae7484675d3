"""Lossless, JSON-safe dictionaries for curves and surfaces.

Floats are stored as Python floats (``json`` writes their shortest repr,
which reads back bit-identical), so ``from_dict(json.loads(json.dumps(
to_dict(x))))`` reproduces every knot, control point and weight exactly.
"""

from __future__ import annotations

from typing import Any

from cardionurbs.errors import NurbsInputError

__all__ = ["curve_to_dict", "curve_fields", "surface_to_dict", "surface_fields"]

_FORMAT = 1


def curve_to_dict(curve: Any) -> dict[str, Any]:
    """Dict of a :class:`~cardionurbs.nurbs.curve.NurbsCurve` (lossless, JSON-safe).

    Parameters
    ----------
    curve : NurbsCurve

    Returns
    -------
    dict
        ``type``, ``format``, ``degree``, ``closed``, ``knots``, ``control_points``, ``weights``.
    """
    return {
        "type": "NurbsCurve", "format": _FORMAT,
        "degree": int(curve.degree), "closed": bool(curve.closed),
        "knots": curve.knots.tolist(),
        "control_points": curve.control_points.tolist(),
        "weights": curve.weights.tolist(),
    }


def _field(data: dict[str, Any], key: str, kind: str) -> Any:
    if not isinstance(data, dict):
        raise NurbsInputError(f"data: expected a dict for a {kind}, got {type(data).__name__}")
    if key not in data:
        raise NurbsInputError(f"data: missing field '{key}' for a {kind}")
    return data[key]


def _typed_fields(data: dict[str, Any], kind: str, keys: tuple[str, ...]) -> list[Any]:
    """The values of ``keys`` of a dict whose ``type`` must be ``kind``."""
    found = _field(data, "type", kind)
    if found != kind:
        raise NurbsInputError(f"data: field 'type' is {found!r}, expected {kind!r}")
    return [_field(data, key, kind) for key in keys]


def curve_fields(data: dict[str, Any]) -> tuple[list[Any], dict[str, Any]]:
    """Constructor arguments of the curve a :func:`curve_to_dict` dict describes
    (``NurbsCurve.from_dict`` builds it; this module knows no class).

    Parameters
    ----------
    data : dict

    Returns
    -------
    args : list
    kwargs : dict

    Raises
    ------
    NurbsInputError
        A missing or mistyped field (named).
    """
    fields = _typed_fields(data, "NurbsCurve", ("degree", "knots", "control_points", "weights"))
    return fields, {"closed": bool(data.get("closed", False))}


def surface_to_dict(surface: Any) -> dict[str, Any]:
    """Dict of a :class:`~cardionurbs.nurbs.surface.NurbsSurface` (lossless, JSON-safe).

    Parameters
    ----------
    surface : NurbsSurface

    Returns
    -------
    dict
    """
    return {
        "type": "NurbsSurface", "format": _FORMAT,
        "degree_u": int(surface.degree_u), "degree_v": int(surface.degree_v),
        "closed_u": bool(surface.closed_u),
        "knots_u": surface.knots_u.tolist(), "knots_v": surface.knots_v.tolist(),
        "control_points": surface.control_points.tolist(),
        "weights": surface.weights.tolist(),
    }


def surface_fields(data: dict[str, Any]) -> tuple[list[Any], dict[str, Any]]:
    """Constructor arguments of the surface a :func:`surface_to_dict` dict describes
    (``NurbsSurface.from_dict`` builds it).

    Parameters
    ----------
    data : dict

    Returns
    -------
    args : list
    kwargs : dict

    Raises
    ------
    NurbsInputError
        A missing or mistyped field (named).
    """
    fields = _typed_fields(data, "NurbsSurface", ("degree_u", "degree_v", "knots_u", "knots_v",
                                                   "control_points", "weights"))
    return fields, {"closed_u": bool(data.get("closed_u", False))}
