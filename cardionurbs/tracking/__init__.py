"""Tag tracking from SPAMM-tagged images: spectral tag geometry, harmonic phase (HARP) tracking,
and tracked tag lines with 3-D tag indices (:func:`track_tags`)."""

from cardionurbs.tracking.track import track_tags

__all__ = ["track_tags"]
