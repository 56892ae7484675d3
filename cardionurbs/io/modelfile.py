"""The model file: ``model.json`` (version 2, compact) or ``model.npz``, and version 1.

What a model file holds is what defines the model and nothing that can be derived
(docs/formats.md, "model.json"): per frame and surface the NURBS degrees, knots, control
points and weights; the valve planes, apex points, outflow tracts, ED/ES, the apex and
mitral landmarks the long axis comes from; the tag surfaces of a tagged study. The SA
sections of version 1 (the study's contours, re-read from the study) are left out.

Stated precision (version 2)
    control points: integers of :data:`UNIT_MM` (10 nm), exact to ±5 nm (the tag
    surfaces': of :data:`TAG_UNIT_MM`, 0.1 µm);
    knots: integers of :data:`KNOT_UNIT` (1e-9 of the parameter range);
    weights: float64 (exact), left out of a surface whose weights are all 1.
    Everything else (planes, apex points, landmarks) is JSON's shortest exact form.

Encoding
    The numbers of every surface (in the order the file lists them) are concatenated
    into three streams, ``arrays.control_points`` (int32 differences with a lag of 3:
    each coordinate minus the same coordinate of the previous point), ``arrays.knots``
    (int32 differences with lag 1) and ``arrays.weights`` (float64), and the tag
    surfaces' likewise into ``tag_control_points``, ``tag_knots``, ``tag_weights``
    (each stream's dtype, count and unit are in ``arrays``); each stream is
    byte-shuffled (all first bytes, then all second bytes ...: the high bytes of small
    differences are alike, and deflate finds them), deflated (zlib) and, in JSON,
    base64-encoded. A surface gives the shapes of its parts, read from the streams in
    the order the surfaces are listed (knots in key order, then control points, then
    weights): ``"control_points": [nu, nv, 3]``, ``"knots_u": n``, ``"weights": [nu, nv]``
    (absent: all 1).
    ``model.npz`` (a deflated zip that ``numpy.load`` reads) holds the same streams as
    uint8 members (not base64) and the rest as the JSON text of the member
    ``model.json``; its members carry a fixed time (1980-01-01, the zip format's
    earliest), so the same model gives the same bytes.

Version 1 files (every float as JSON text, with the SA sections) still load:
:func:`unpack` passes them through.
"""

from __future__ import annotations

import base64
import io
import json
import os
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from cardionurbs.errors import ExportError
from cardionurbs.io import atomic

__all__ = ["pack", "unpack", "write_model_file", "read_model_file", "UNIT_MM", "TAG_UNIT_MM",
           "KNOT_UNIT"]

VERSION = 2
#: control points are stored as integers of this length (mm)
UNIT_MM = 1e-5
#: tag surfaces' control points are stored as integers of this length (mm)
TAG_UNIT_MM = 1e-4
#: knots are stored as integers of this parameter step
KNOT_UNIT = 1e-9
STREAMS = ("control_points", "knots", "weights")
STREAM_NAMES = STREAMS + tuple("tag_" + k for k in STREAMS)
_NURBS = ("NurbsSurface", "NurbsCurve")
#: version-1 keys that are derivable and not written any more
DERIVABLE = ("sections",)


class _Streams:
    """The three number streams of one group of surfaces being packed (control points as
    integers of ``unit_mm``, knots, weights)."""

    def __init__(self, unit_mm: float) -> None:
        self.unit_mm = float(unit_mm)
        self.cp: list[np.ndarray] = []
        self.knots: list[np.ndarray] = []
        self.weights: list[np.ndarray] = []

    def add_cp(self, a: Any) -> list[int]:
        a = np.asarray(a, float)
        self.cp.append(np.round(a.ravel() / self.unit_mm).astype(np.int64))
        return list(a.shape)

    def add_knots(self, a: Any) -> int:
        a = np.asarray(a, float).ravel()
        self.knots.append(np.round(a / KNOT_UNIT).astype(np.int64))
        return int(a.size)

    def add_weights(self, a: Any) -> list[int] | None:
        a = np.asarray(a, float)
        if np.all(a == 1.0):
            return None
        self.weights.append(a.ravel())
        return list(a.shape)


class _Cursor:
    """Reads the decoded streams in the order :class:`_Streams` wrote them."""

    def __init__(self, arrays: dict[str, np.ndarray]) -> None:
        self.arrays = arrays
        self.at = {k: 0 for k in arrays}

    def take(self, name: str, shape) -> np.ndarray:
        n = int(np.prod(shape))
        o = self.at[name]
        a = self.arrays[name][o:o + n]
        if a.size != n:
            raise ExportError(f"model file: the {name} stream ends early")
        self.at[name] = o + n
        return a.reshape(shape)


def _shuffled(a: np.ndarray) -> bytes:
    """The bytes of ``a`` grouped by byte position (a byte-shuffle filter), deflated."""
    b = np.ascontiguousarray(a).view(np.uint8).reshape(-1, a.dtype.itemsize)
    return zlib.compress(b.T.tobytes(), 9)


def _unshuffled(data: bytes, dtype: str, count: int) -> np.ndarray:
    size = np.dtype(dtype).itemsize
    raw = np.frombuffer(zlib.decompress(data), np.uint8)
    if raw.size != size * count:
        raise ExportError(f"model file: a stream holds {raw.size} bytes, expected {size * count}")
    return raw.reshape(size, count).T.copy().view(dtype).ravel()


def _deltas(q: np.ndarray, lag: int) -> np.ndarray:
    d = q.copy()
    d[lag:] -= q[:-lag]
    if d.size and np.abs(d).max() >= 2 ** 31:
        raise ExportError("model file: a coordinate step beyond the int32 range of the stream")
    return d.astype("<i4")


def _integrate(d: np.ndarray, lag: int) -> np.ndarray:
    q = d.astype(np.int64)
    for i in range(lag):
        q[i::lag] = np.cumsum(q[i::lag])
    return q


def _pack_nurbs(d: dict, s: _Streams) -> dict:
    out = {k: v for k, v in d.items() if k not in ("control_points", "weights")
           and not k.startswith("knots")}
    for k in sorted(d):
        if k.startswith("knots"):
            out[k] = s.add_knots(d[k])
    out["control_points"] = s.add_cp(d["control_points"])
    w = s.add_weights(d["weights"])
    if w is not None:
        out["weights"] = w
    return out


def _walk(x: Any, fn) -> Any:
    """``x`` with every NURBS dict replaced by ``fn(dict)`` (lists and dicts copied)."""
    if isinstance(x, dict):
        if x.get("type") in _NURBS:
            return fn(x)
        return {k: _walk(v, fn) for k, v in x.items()}
    if isinstance(x, list):
        return [_walk(v, fn) for v in x]
    return x


def _group_streams(s: _Streams) -> tuple[dict, dict[str, bytes]]:
    """The (specs, deflated bytes) of one group's three streams."""
    cp = np.concatenate(s.cp) if s.cp else np.zeros(0, np.int64)
    kn = np.concatenate(s.knots) if s.knots else np.zeros(0, np.int64)
    w = np.concatenate(s.weights) if s.weights else np.zeros(0)
    specs = {"control_points": {"dtype": "<i4", "count": int(cp.size), "lag": 3, "unit": s.unit_mm},
             "knots": {"dtype": "<i4", "count": int(kn.size), "lag": 1, "unit": KNOT_UNIT},
             "weights": {"dtype": "<f8", "count": int(w.size)}}
    data = {"control_points": _shuffled(_deltas(cp, 3)), "knots": _shuffled(_deltas(kn, 1)),
            "weights": _shuffled(w.astype("<f8"))}
    return specs, data


def pack(model_dict: dict) -> tuple[dict, dict[str, bytes]]:
    """A version-1 model dict (:meth:`BiventricularModel.to_dict`, optionally with
    ``tag_surfaces``) as the version-2 header and its deflated streams.

    The heart's surfaces (and anything else but the tag surfaces) go to the streams
    ``control_points``, ``knots``, ``weights`` (control points in :data:`UNIT_MM`); the
    tag surfaces to ``tag_control_points``, ``tag_knots``, ``tag_weights`` (in
    :data:`TAG_UNIT_MM`: no metric of a read-back model uses them).

    Parameters
    ----------
    model_dict : dict
        The model as plain lists and floats.

    Returns
    -------
    header : dict
        The file's JSON without the stream data (``arrays`` gives each stream's dtype,
        count and unit).
    streams : dict name -> bytes
        The six streams, shuffled and deflated.
    """
    body = {k: v for k, v in model_dict.items() if k not in DERIVABLE}
    heart, tags = _Streams(UNIT_MM), _Streams(TAG_UNIT_MM)
    body = {k: _walk(v, lambda d, st=(tags if k == "tag_surfaces" else heart):
                     _pack_nurbs(d, st)) for k, v in body.items()}
    arrays: dict = {"encoding": "byte-shuffled, zlib"}
    streams: dict[str, bytes] = {}
    for prefix, st in (("", heart), ("tag_", tags)):
        specs, data = _group_streams(st)
        arrays.update({prefix + k: v for k, v in specs.items()})
        streams.update({prefix + k: v for k, v in data.items()})
    header = {**body, "version": VERSION,
              "precision": {"control_points_mm": UNIT_MM, "tag_control_points_mm": TAG_UNIT_MM,
                            "knots": KNOT_UNIT, "weights": "float64"},
              "arrays": arrays}
    return header, streams


def _decoded(header: dict, streams: dict[str, bytes], prefix: str) -> dict[str, np.ndarray]:
    """One group's streams as numbers (mm, parameter units, weights)."""
    out = {}
    for name in STREAMS:
        spec = header["arrays"][prefix + name]
        a = _unshuffled(streams[prefix + name], spec["dtype"], int(spec["count"]))
        if "lag" in spec:
            a = _integrate(a, int(spec["lag"])) * float(spec["unit"])
        out[name] = a
    return out


def _unpack_nurbs(d: dict, at: _Cursor) -> dict:
    out = dict(d)
    for k in sorted(d):
        if k.startswith("knots"):
            out[k] = at.take("knots", (int(d[k]),)).tolist()
    shape = tuple(d["control_points"])
    out["control_points"] = at.take("control_points", shape).tolist()
    w = d.get("weights")
    out["weights"] = (np.ones(shape[:-1]) if w is None else at.take("weights", tuple(w))).tolist()
    return out


def unpack(d: dict, streams: dict[str, bytes] | None = None) -> dict:
    """The version-1 dict of a model file's content (version 1: ``d`` itself).

    Parameters
    ----------
    d : dict
        A model file's JSON (version 1 or 2).
    streams : dict name -> bytes, optional
        The deflated streams when they are not in ``d`` (``model.npz``); by default the
        base64 ``data`` of ``d["arrays"]``.

    Returns
    -------
    dict
        Plain lists and floats, as :meth:`BiventricularModel.from_dict` reads them.
    """
    if int(d.get("version", 1)) < 2:
        return d
    if streams is None:
        try:
            streams = {k: base64.b64decode(d["arrays"][k]["data"]) for k in STREAM_NAMES}
        except (KeyError, TypeError, ValueError) as exc:
            raise ExportError(f"model file: its arrays cannot be read ({exc})") from None
    heart, tags = (_Cursor(_decoded(d, streams, p)) for p in ("", "tag_"))
    body = {k: v for k, v in d.items() if k not in ("arrays", "precision")}
    body = {k: _walk(v, lambda x, at=(tags if k == "tag_surfaces" else heart):
                     _unpack_nurbs(x, at)) for k, v in body.items()}
    body["version"] = 1
    return body


#: the time stamped on every member of a model.npz (the zip format's earliest)
ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def _npz_bytes(members: dict[str, np.ndarray]) -> bytes:
    """The bytes of a deflated ``.npz`` of ``members``, the same for the same arrays
    (``numpy.savez_compressed`` stamps each member with the current time)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, a in members.items():
            info = zipfile.ZipInfo(name + ".npy", date_time=ZIP_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            with z.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asarray(a), allow_pickle=False)
    return buf.getvalue()


def write_model_file(model_dict: dict, path: str | os.PathLike) -> Path:
    """Write a model dict compactly: ``.json`` (streams base64 inline) or ``.npz``,
    atomically.

    Parameters
    ----------
    model_dict : dict
        The version-1 model dict (:meth:`BiventricularModel.to_dict
        <cardionurbs.anatomy.model.BiventricularModel.to_dict>`).
    path : str or os.PathLike
        The file to write; its suffix, ``.json`` or ``.npz``, chooses the container.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ExportError
        A suffix other than ``.json`` or ``.npz``.
    """
    path = Path(path)
    header, streams = pack(model_dict)
    if path.suffix.lower() == ".npz":
        members = {k: np.frombuffer(v, np.uint8) for k, v in streams.items()}
        members["model.json"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
        return atomic.write_bytes(path, _npz_bytes(members))
    if path.suffix.lower() != ".json":
        raise ExportError(f"{path}: a model file is .json or .npz")
    for k, v in streams.items():
        header["arrays"][k]["data"] = base64.b64encode(v).decode("ascii")
    try:
        text = json.dumps(header, separators=(",", ":"), allow_nan=False)
    except ValueError:                            # NaN / infinity -> null
        from cardionurbs.io.export import _json_safe
        text = json.dumps(_json_safe(header), separators=(",", ":"))
    return atomic.write_text(path, text + "\n")


def read_model_file(path: str | os.PathLike) -> dict:
    """The version-1 dict of a ``model.json`` (version 1 or 2) or ``model.npz``.

    Parameters
    ----------
    path : str or os.PathLike
        The model file.

    Returns
    -------
    dict
        The model dict :meth:`BiventricularModel.from_dict
        <cardionurbs.anatomy.model.BiventricularModel.from_dict>` reads.

    Raises
    ------
    ExportError
        The file cannot be read or is not a cardionurbs model file.
    """
    path = Path(path)
    try:
        if path.suffix.lower() == ".npz":
            with np.load(path, allow_pickle=False) as z:
                header = json.loads(z["model.json"].tobytes())
                streams = {k: z[k].tobytes() for k in STREAM_NAMES}
            return unpack(header, streams)
        return unpack(json.loads(path.read_text()))
    except (OSError, ValueError, KeyError, zlib.error) as exc:
        raise ExportError(f"{path}: not a readable cardionurbs model file ({exc})") from None
