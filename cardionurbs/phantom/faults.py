"""Faults injected into phantom annotations on request; each is recorded in truth["faults"].

* **Contour/tag noise** (``noise_px``): i.i.d. Gaussian noise of standard
  deviation σ pixels added to the column and row coordinates of every contour
  and tag-line point (the point stays on its image plane).
* **Tag jumping** (``tag_jumps`` = K): on K distinct (SA slice, frame ≠ ED)
  pairs, one SA tag line (family, index) is replaced by the points of its
  neighbour (index ± 1 of the same family on the same image): it lies one tag
  spacing off and keeps its index — the tracking error of the paper's Fig. 8.
* **Breath-hold slice shifts** (``breath_hold_mm`` = σ): each SA slice is
  acquired in a different breath hold, so the heart seen on it is displaced
  in-plane by a Gaussian vector (σ mm per axis) for all frames; the images,
  contours, tags and landmarks of that slice move together while the recorded
  plane geometry does not.
"""

from __future__ import annotations

import numpy as np

from cardionurbs.errors import PhantomError
from cardionurbs.study import Study


def add_noise(study: Study, sigma_px: float, rng: np.random.Generator, tries: int = 50,
              targets: tuple[str, ...] = ("contours", "tags")) -> list[dict]:
    """Add N(0, σ²) pixel noise to every contour and tag-line point, in place.

    ``targets``: which annotations get the noise, "contours" and/or "tags" (e.g. only
    ("tags",) to study tag tracking noise with exact contours).

    A closed contour is never drawn crossing itself (an analyst would not): a draw that makes one
    cross (thin apical RV crescents, whose tips are narrower than the noise) is drawn again from
    a generator of its own (seeded from ``rng``'s draw for it, so every other contour gets
    exactly the noise it would get without the redraws), up to ``tries`` times; a contour that
    crosses under every draw is left out, as an analyst leaves out a crescent thinner than the
    noise. Returns the left-out contours (slice, frame, structure).

    Parameters
    ----------
    study : cardionurbs.study.Study
        The phantom's study (contour and tag points changed in place).
    sigma_px : float
        σ, in pixels (0 or less: no noise).
    rng : numpy.random.Generator
        The phantom's random generator.
    tries : int, optional
        Draws of a crossing contour before it is left out.
    targets : tuple of str, optional
        ``"contours"`` and/or ``"tags"``.

    Returns
    -------
    list of dict
        ``{"slice", "frame", "structure"}`` of every contour left out.

    Raises
    ------
    cardionurbs.errors.PhantomError
        ``targets`` names anything else.
    """
    from cardionurbs.io.checks import in_plane_coordinates, self_intersections
    if not set(targets) <= {"contours", "tags"}:
        raise PhantomError(f"targets: 'contours' and/or 'tags', not {targets!r}")
    if sigma_px <= 0:
        return []
    dropped, keep = [], []
    for item in [*(study.contours if "contours" in targets else ()),
                 *(study.tags if "tags" in targets else ())]:
        im = study.image(item.image)

        def noisy(d):
            return (item.points + d[:, :1] * im.pixel_spacing[1] * im.row_cosine
                    + d[:, 1:] * im.pixel_spacing[0] * im.column_cosine)

        d = rng.normal(0.0, sigma_px, size=(len(item.points), 2))
        pts = noisy(d)

        def crosses(p):
            return bool(len(self_intersections(in_plane_coordinates(p, im), True, first=True)))

        if getattr(item, "closed", False) and crosses(pts):
            own = np.random.default_rng(np.abs(d[:4].ravel() * 1e6).astype(np.int64))
            for _ in range(tries):
                pts = noisy(own.normal(0.0, sigma_px, size=d.shape))
                if not crosses(pts):
                    break
            else:
                dropped.append({"slice": item.slice, "frame": int(item.frame),
                                "structure": item.structure})
                keep.append(id(item))
                continue
        item.points = pts
    if keep:
        study.contours[:] = [c for c in study.contours if id(c) not in keep]
    return dropped


def inject_tag_jumps(study: Study, k: int, rng: np.random.Generator) -> list[dict]:
    """Replace one SA tag line by its neighbour's on k (slice, frame ≠ ED) pairs, in place.

    Parameters
    ----------
    study : cardionurbs.study.Study
        The phantom's study (tag lines changed in place).
    k : int
        Tag jumps to inject (0 or less: none).
    rng : numpy.random.Generator
        The phantom's random generator.

    Returns
    -------
    list of dict
        ``{"slice", "frame", "family", "index", "replaced_by_index"}`` per jump.

    Raises
    ------
    cardionurbs.errors.PhantomError
        ``k`` exceeds the tagged SA (slice, frame) pairs after ED.
    """
    if k <= 0:
        return []
    by_image: dict[tuple[str, int], dict[tuple[str, int], object]] = {}
    for t in study.tags:
        if t.view == "SA" and t.frame != 0:
            by_image.setdefault((t.slice, t.frame), {})[(t.family, t.index)] = t
    pairs = sorted(p for p, lines in by_image.items()
                   if any((f, i + 1) in lines or (f, i - 1) in lines for f, i in lines))
    if k > len(pairs):
        raise PhantomError(f"tag_jumps={k} exceeds the {len(pairs)} tagged SA (slice, frame) pairs "
                           "after ED")
    chosen = rng.choice(len(pairs), size=k, replace=False)
    record = []
    for c in sorted(int(x) for x in chosen):
        key = pairs[c]
        lines = by_image[key]
        cands = sorted(fi for fi in lines if (fi[0], fi[1] + 1) in lines or (fi[0], fi[1] - 1) in lines)
        fam, idx = cands[int(rng.integers(len(cands)))]
        options = [j for j in (idx - 1, idx + 1) if (fam, j) in lines]
        nb = options[int(rng.integers(len(options)))]
        lines[(fam, idx)].points = lines[(fam, nb)].points.copy()
        record.append({"slice": key[0], "frame": int(key[1]), "family": fam, "index": int(idx),
                       "replaced_by_index": int(nb)})
    return record


def breath_hold_offsets(slice_ids: list[str], sigma_mm: float, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """In-plane (row, column) displacement in mm of each SA slice (zeros when σ = 0).

    Parameters
    ----------
    slice_ids : list of str
        The SA slice ids.
    sigma_mm : float
        σ per in-plane axis, in mm.
    rng : numpy.random.Generator
        The phantom's random generator.

    Returns
    -------
    dict of str to ndarray
        Slice id -> (row, column) displacement (2,), in mm.
    """
    if sigma_mm <= 0:
        return {s: np.zeros(2) for s in slice_ids}
    return {s: rng.normal(0.0, sigma_mm, size=2) for s in slice_ids}
