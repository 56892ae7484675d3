"""Label conventions of segmentation label maps: which integer is which structure.

A :class:`LabelRoles` says which label value is the LV cavity (``lv``), the LV
myocardium (``myo``), the RV cavity (``rv``) and, where a convention has them,
the RV myocardium (``rv_myo``), left atrium (``la``) and right atrium (``ra``).

Presets (``PRESETS``)
    ``acdc``   1 RV cavity, 2 LV myocardium, 3 LV cavity (ACDC challenge);
    ``ukbb``   1 LV cavity, 2 LV myocardium, 3 RV cavity, 4 left atrium,
               5 right atrium (UK Biobank / ukbb_cardiac; 4 and 5 appear only
               in the 4-chamber ``seg4_la_4ch`` maps);
    ``mnms``   1 LV cavity, 2 LV myocardium, 3 RV cavity (M&Ms challenge);
    ``bivme``  1 LV cavity, 2 LV myocardium, 3 RV cavity, 4 RV myocardium
               (biv-me's contouring tests).

An explicit mapping reads ``lv=3,myo=2,rv=1`` (optionally ``rv_myo=``, ``la=``,
``ra=``). With no convention given, :func:`infer_roles` reads the roles from
the topology of the short-axis maps: the LV cavity is the label that another
label (the myocardium) rings in most slices; the RV cavity is the remaining
label that touches the ring from outside over the longest boundary.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from cardionurbs.errors import StudyError

ROLES = ("lv", "myo", "rv", "rv_myo", "la", "ra")


@dataclass(frozen=True)
class LabelRoles:
    """Label value of each structure (None where the convention has none).

    Attributes
    ----------
    lv, myo : int
        The label values of the LV cavity and the LV myocardium.
    rv, rv_myo, la, ra : int or None
        Those of the RV cavity, the RV myocardium and the atria (None: not labelled).
    name : str
        The convention's name (a preset's, or ``mapping``).

    Raises
    ------
    StudyError
        One label value given two roles.
    """

    lv: int
    myo: int
    rv: int | None = None
    rv_myo: int | None = None
    la: int | None = None
    ra: int | None = None
    name: str = "mapping"

    def __post_init__(self) -> None:
        vals = [v for v in self.values().values()]
        if len(set(vals)) != len(vals):
            raise StudyError(f"label convention {self.describe()}: one label value has two roles",
                             field="labels")
        if any(v <= 0 for v in vals):
            raise StudyError(f"label convention {self.describe()}: label values must be >= 1 "
                             "(0 is background)", field="labels")

    def values(self) -> dict[str, int]:
        """Role -> label value, for the roles this convention has.

        Returns
        -------
        dict of str to int
        """
        return {r: getattr(self, r) for r in ROLES if getattr(self, r) is not None}

    def describe(self) -> str:
        """``acdc (lv=3, myo=2, rv=1)``: the name and the mapping, for messages.

        Returns
        -------
        str
        """
        return f"{self.name} (" + ", ".join(f"{r}={v}" for r, v in self.values().items()) + ")"


PRESETS: dict[str, LabelRoles] = {
    "acdc": LabelRoles(lv=3, myo=2, rv=1, name="acdc"),
    "ukbb": LabelRoles(lv=1, myo=2, rv=3, la=4, ra=5, name="ukbb"),
    "mnms": LabelRoles(lv=1, myo=2, rv=3, name="mnms"),
    "bivme": LabelRoles(lv=1, myo=2, rv=3, rv_myo=4, name="bivme"),
}


def parse_labels(spec: "str | LabelRoles | None") -> LabelRoles | None:
    """A preset name, an explicit ``lv=…,myo=…,rv=…`` mapping, a LabelRoles, or None (infer).

    Parameters
    ----------
    spec : str, LabelRoles or None
        ``acdc``, ``ukbb``, ``mnms``, ``bivme``, or ``lv=3,myo=2,rv=1``-style text.

    Returns
    -------
    LabelRoles or None
        None: infer the roles from the map (:func:`infer_roles`).

    Raises
    ------
    StudyError
        An unknown preset or a malformed mapping.
    """
    if spec is None or isinstance(spec, LabelRoles):
        return spec
    text = str(spec).strip()
    if text.lower() in PRESETS:
        return PRESETS[text.lower()]
    if "=" not in text:
        raise StudyError(f"unknown label convention {text!r}; expected one of "
                         f"{', '.join(PRESETS)} or a mapping such as lv=3,myo=2,rv=1",
                         field="labels")
    roles: dict[str, int] = {}
    for part in text.split(","):
        m = re.fullmatch(r"\s*([a-z_]+)\s*=\s*(\d+)\s*", part)
        if not m or m.group(1) not in ROLES:
            raise StudyError(f"bad label mapping {part.strip()!r}; expected role=value with role "
                             f"one of {', '.join(ROLES)}", field="labels")
        if m.group(1) in roles:
            raise StudyError(f"label mapping names {m.group(1)} twice", field="labels")
        roles[m.group(1)] = int(m.group(2))
    if "lv" not in roles or "myo" not in roles:
        raise StudyError("label mapping needs at least lv= and myo=", field="labels")
    return LabelRoles(**roles, name="mapping")


def check_values(present: set[int], roles: LabelRoles, where: str) -> None:
    """StudyError when the map holds a label the convention does not name.

    Parameters
    ----------
    present : set of int
        The label values in the map (0, background, allowed).
    roles : LabelRoles
        The convention.
    where : str
        The file, for the message.

    Raises
    ------
    StudyError
        A label value the convention does not name.
    """
    extra = sorted(present - set(roles.values().values()) - {0})
    if extra:
        mapping = ",".join(f"{r}={v}" for r, v in roles.values().items())
        free = [r for r in ROLES if getattr(roles, r) is None]
        hint = f"{mapping},ROLE={extra[0]} with ROLE one of {', '.join(free)}" if free else mapping
        raise StudyError(f"label {extra[0]} is not in the label convention {roles.describe()} "
                         f"(values present: {', '.join(map(str, sorted(present - {0})))}; name "
                         f"the map's own convention with --labels, e.g. {hint})",
                         file=where, field="labels")


# ------------------------------------------------------------------ topology
def _ring_score(vol: np.ndarray, a: int, b: int) -> int:
    """Number of 2-D slices (axis 2, every frame) in which label b rings label a: at least
    90 % of a's pixels lie in the holes of b's mask."""
    n = 0
    for sl in _slices(vol):
        ma = sl == a
        if ma.sum() < 4:
            continue
        mb = sl == b
        if not mb.any():
            continue
        holes = ndimage.binary_fill_holes(mb) & ~mb
        if (holes & ma).sum() >= 0.9 * ma.sum():
            n += 1
    return n


def _slices(vol: np.ndarray):
    v = vol.reshape(vol.shape[0], vol.shape[1], -1)
    for k in range(v.shape[2]):
        yield v[:, :, k]


def _contact(vol: np.ndarray, a: int, b: int) -> int:
    """In-plane 4-neighbour contacts between labels a and b (pixel pairs)."""
    v = vol.reshape(vol.shape[0], vol.shape[1], -1)
    n = 0
    for x, y in ((v[1:], v[:-1]), (v[:, 1:], v[:, :-1])):
        n += int(((x == a) & (y == b)).sum() + ((x == b) & (y == a)).sum())
    return n


def infer_roles(vol: np.ndarray, where: str = "") -> tuple[LabelRoles, str]:
    """Roles of the labels of a short-axis label volume from topology.

    LV cavity = the label ``a`` that some label ``b`` (the myocardium) rings in the most
    slices; RV cavity = the remaining label with the longest boundary with the myocardium;
    a further label sharing the longest boundary with the RV cavity outside the ring is the
    RV myocardium. StudyError when no ring is found, or when two readings of the map are
    equally good.

    Parameters
    ----------
    vol : (x, y, slices[, frames]) int ndarray
        The label volume (0 is background).
    where : str
        The file, for the errors.

    Returns
    -------
    roles : LabelRoles
        Named ``inferred``.
    note : str
        One line describing what was inferred (and which presets it agrees with).
    """
    present = sorted(int(v) for v in np.unique(vol) if v != 0)
    if len(present) < 2:
        raise StudyError("cannot infer the label convention: the map needs at least an LV cavity "
                         f"and a myocardium label, it holds {present or 'no labels'}",
                         file=where, field="labels")
    lv, myo = _ringed_pair(vol, present, where)
    rest = [v for v in present if v not in (lv, myo)]
    rv = rv_myo = None
    if rest:
        rv = _rv_cavity(vol, rest, myo, where)
        rv_myo = _rv_myocardium(vol, [v for v in rest if v != rv], (lv, myo, rv), where)
    roles = LabelRoles(lv=lv, myo=myo, rv=rv, rv_myo=rv_myo, name="inferred")
    return roles, _inferred_note(roles, present)


def _ringed_pair(vol: np.ndarray, present: list[int], where: str) -> tuple[int, int]:
    """(LV cavity, myocardium): the pair (a, b) with b ringing a in the most slices.

    Parameters
    ----------
    vol : (x, y, slices[, frames]) int ndarray
        The label volume.
    present : list of int
        Its non-zero labels, ascending.
    where : str
        The file, for the error.

    Returns
    -------
    (int, int)
        The ringed label and the label ringing it; StudyError when no pair rings or two
        pairs ring in as many slices.
    """
    scores = {(a, b): _ring_score(vol, a, b) for a in present for b in present if a != b}
    best = max(scores.values())
    top = [k for k, s in scores.items() if s == best]
    if best == 0:
        raise StudyError(f"cannot infer the label convention: no label of {present} is ringed by "
                         "another (no myocardium around an LV cavity); give --labels",
                         file=where, field="labels")
    if len(top) > 1:
        raise StudyError(f"ambiguous label map: labels {top[0][0]} and {top[1][0]} are both "
                         "ringed by another label in as many slices; give --labels "
                         "(e.g. acdc, ukbb or lv=…,myo=…,rv=…)", file=where, field="labels")
    return top[0]


def _rv_cavity(vol: np.ndarray, rest: list[int], myo: int, where: str) -> int:
    """The RV cavity: of the labels ``rest`` (neither LV cavity nor myocardium), the one
    with the longest boundary with the myocardium ``myo``.

    Parameters
    ----------
    vol : (x, y, slices[, frames]) int ndarray
    rest : list of int
        The candidate labels (at least one).
    myo : int
        The myocardium label.
    where : str
        The file, for the error.

    Returns
    -------
    int
        The RV cavity label; StudyError when none touches the myocardium or two touch it
        equally.
    """
    contact = {v: _contact(vol, v, myo) for v in rest}
    order = sorted(rest, key=lambda v: -contact[v])
    if contact[order[0]] == 0:
        raise StudyError(f"cannot infer the label convention: none of labels {rest} touches "
                         f"the myocardium (label {myo}); give --labels", file=where,
                         field="labels")
    if len(order) > 1 and contact[order[1]] == contact[order[0]]:
        raise StudyError(f"ambiguous label map: labels {order[0]} and {order[1]} touch the "
                         "myocardium equally; give --labels", file=where, field="labels")
    return order[0]


def _rv_myocardium(vol: np.ndarray, others: list[int], known: tuple[int, int, int],
                   where: str) -> int | None:
    """The RV myocardium: of the labels ``others`` left over, the one with the longest
    boundary with the RV cavity (None when none touches it).

    Parameters
    ----------
    vol : (x, y, slices[, frames]) int ndarray
    others : list of int
        The labels left once LV cavity, myocardium and RV cavity are known (may be empty).
    known : (int, int, int)
        (LV cavity, myocardium, RV cavity), for the error.
    where : str
        The file, for the error.

    Returns
    -------
    int or None
        The RV myocardium label; StudyError when any other label is left without a role.
    """
    if not others:
        return None
    lv, myo, rv = known
    c_rv = {v: _contact(vol, v, rv) for v in others}
    cand = max(others, key=lambda v: c_rv[v])
    rv_myo = cand if c_rv[cand] > 0 else None
    left = [v for v in others if v != rv_myo]
    if left:
        raise StudyError(f"cannot infer the role of label(s) {left} (the LV cavity is "
                         f"{lv}, myocardium {myo}, RV {rv}); give --labels", file=where,
                         field="labels")
    return rv_myo


def _inferred_note(roles: LabelRoles, present: list[int]) -> str:
    """The one-line note of an inferred convention, naming the presets it agrees with.

    Parameters
    ----------
    roles : LabelRoles
        The inferred roles.
    present : list of int
        The map's non-zero labels.

    Returns
    -------
    str
    """
    same = [n for n, p in PRESETS.items()
            if {k: v for k, v in p.values().items() if v in present} == roles.values()]
    return (f"label convention inferred from topology: {roles.describe()}"
            + (f" (as {'/'.join(same)})" if same else "") + "; give --labels to set it")
