"""Documented limits on input size, so that any valid study finishes in bounded time and memory.

Past a limit the readers raise :class:`~cardionurbs.errors.LimitError` (a
:class:`~cardionurbs.errors.StudyError`: CLI exit 2, one line naming the file,
slice and frame). The limits sit well above real cardiac MR studies (a
Sunnybrook contour has ~100-300 points, a CAP study ~30 frames and a few
thousand contours) and keep the work bounded: every per-contour step is
O(n log n) in the points of the contour (the self-intersection test is a
sorted sweep, :func:`cardionurbs.io.checks.self_intersections`), so a study at
the limits is measured within minutes and a few GB; see ``reports/limits.md``
for measured times and memory.
"""

from __future__ import annotations

#: points in one contour, tag line or landmark group
MAX_POINTS_PER_CONTOUR = 10_000
#: contours (and separately tag lines) in one study
MAX_CONTOURS_PER_STUDY = 50_000
#: annotation points in one study (all contours, tags and landmarks)
MAX_POINTS_PER_STUDY = 2_000_000
#: cardiac frames (phases) in one study
MAX_FRAMES = 512
#: voxels in one label map, all frames (checked from the header before any allocation;
#: a UK Biobank SA map is ~2e7, ACDC ~3e6)
MAX_LABEL_VOXELS = 2**28
#: voxels along one axis of a label map
MAX_LABEL_AXIS = 4096
#: bytes a compressed input may expand to (gzip: its ISIZE trailer and the header's shape)
MAX_DECOMPRESSED_BYTES = 2 * 1024**3
#: image planes in one study
MAX_IMAGES = 100_000
#: characters in a subject name, a slice id, an image id or a structure name
MAX_NAME_LENGTH = 128
#: nesting depth of study.json
MAX_JSON_DEPTH = 16
#: size of study.json, bytes
MAX_MANIFEST_BYTES = 64 * 1024 * 1024
#: largest coordinate magnitude, mm from the scanner origin (a bore is < 1 m; a value past
#: this is a typo or an attack, and would overflow squares and products downstream)
MAX_COORDINATE_MM = 1e5
#: how far outside its image a contour pixel may lie, pixels (a contour traced on the
#: image's edge may overshoot it by a little)
CONTOUR_PIXEL_MARGIN = 16
#: plausible heart rate, beats per minute (study.json, DICOM HeartRate, --heart-rate)
HEART_RATE_RANGE_BPM = (20.0, 300.0)
#: plausible in-plane pixel spacing, mm (study.json, DICOM PixelSpacing)
PIXEL_SPACING_RANGE_MM = (0.01, 50.0)
#: plausible slice thickness, mm
THICKNESS_RANGE_MM = (0.01, 500.0)
