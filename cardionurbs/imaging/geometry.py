"""Image-plane geometry: pixel <-> scanner (patient LPS, mm) transforms.

Follows DICOM PS3.3 C.7.6.2.1.1 (Image Plane Module):

    P(c, r) = S + c * Δc * X + r * Δr * Y

where S is ImagePositionPatient (centre of the first transmitted pixel),
X the row direction cosine (first three values of ImageOrientationPatient,
the direction in which the column index c grows), Y the column direction
cosine (last three values, the direction in which the row index r grows),
Δc = PixelSpacing[1] (spacing between columns) and Δr = PixelSpacing[0]
(spacing between rows). Pixel coordinates are (c, r) = (x, y) as drawn on
the image, with (0, 0) the centre of the first pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from cardionurbs.errors import StudyError
from cardionurbs.limits import PIXEL_SPACING_RANGE_MM, THICKNESS_RANGE_MM
from cardionurbs.safe import excerpt

VIEWS = ("SA", "LA")


def _dot3(d: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (n, 3) with (3,), written out so that the result is
    bit-identical whatever the memory layout (BLAS may round differently)."""
    return d[:, 0] * v[0] + d[:, 1] * v[1] + d[:, 2] * v[2]


def _vec3(value, name: str, plane_id: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise StudyError(f"{name} must be 3 finite numbers, got {value!r}", field=name,
                         file=None, slice=plane_id)
    return arr


@dataclass(eq=False)
class ImagePlane:
    """One image (one slice at one frame) and its geometry in scanner mm.

    Attributes
    ----------
    id : str
        Image reference, unique in a study (SOPInstanceUID for DICOM input).
    slice : str
        Slice identifier, shared by the frames of one location (``"sa_03"``,
        ``"la_4ch"``).
    view : str
        ``"SA"`` (short axis) or ``"LA"`` (long axis).
    frame : int
        Cardiac phase index, 0-based.
    position : (3,) ndarray
        ImagePositionPatient, mm.
    row_cosine, column_cosine : (3,) ndarray
        ImageOrientationPatient[:3] and [3:], unit vectors.
    pixel_spacing : (2,) tuple
        DICOM PixelSpacing (row spacing, column spacing), mm.
    rows, columns : int
        Image matrix size.
    thickness : float
        SliceThickness, mm.
    trigger_time : float or None
        TriggerTime, ms.
    file : str or None
        Path of the image file relative to the study folder, if any.
    meta : dict
        Reader-specific extras (DICOM: ``instance_number``, ``series_uid``,
        ``series_number``, ``series_description``, ``frame_number``).

    Raises
    ------
    cardionurbs.errors.StudyError
        A position or cosine not 3 finite numbers, cosines not orthonormal, a pixel
        spacing or slice thickness outside its plausible range, an unknown view.
    """

    id: str
    slice: str
    view: str
    frame: int
    position: np.ndarray
    row_cosine: np.ndarray
    column_cosine: np.ndarray
    pixel_spacing: tuple[float, float]
    rows: int = 256
    columns: int = 256
    thickness: float = 8.0
    trigger_time: float | None = None
    file: str | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        pos = _vec3(self.position, "ImagePositionPatient", self.slice)
        rc = _vec3(self.row_cosine, "ImageOrientationPatient", self.slice)
        cc = _vec3(self.column_cosine, "ImageOrientationPatient", self.slice)
        nr, nc = np.linalg.norm(rc), np.linalg.norm(cc)
        if abs(nr - 1) > 1e-3 or abs(nc - 1) > 1e-3 or abs(rc @ cc) > 1e-3:
            raise StudyError("ImageOrientationPatient is not two orthonormal vectors",
                             slice=self.slice, frame=self.frame, field="ImageOrientationPatient")
        sp = tuple(float(s) for s in np.asarray(self.pixel_spacing, dtype=float).reshape(-1))
        lo, hi = PIXEL_SPACING_RANGE_MM
        if len(sp) != 2 or not all(np.isfinite(s) and lo <= s <= hi for s in sp):
            raise StudyError(f"PixelSpacing must be two numbers in [{lo:g}, {hi:g}] mm, got "
                             f"{excerpt(self.pixel_spacing)}",
                             slice=self.slice, frame=self.frame, field="PixelSpacing")
        if self.view not in VIEWS:
            raise StudyError(f"view must be one of {VIEWS}, got {excerpt(self.view)}",
                             slice=self.slice, frame=self.frame, field="view")
        if not (np.isfinite(self.thickness) and 0 < self.thickness <= THICKNESS_RANGE_MM[1]):
            raise StudyError(f"SliceThickness must be in (0, {THICKNESS_RANGE_MM[1]:g}] mm, got "
                             f"{excerpt(self.thickness)}",
                             slice=self.slice, frame=self.frame, field="SliceThickness")
        self.position = pos
        # renormalise only what is visibly off, so written values read back bit-exact
        self.row_cosine = rc / nr if abs(nr - 1) > 1e-12 else rc
        self.column_cosine = cc / nc if abs(nc - 1) > 1e-12 else cc
        self.pixel_spacing = sp
        self.frame, self.rows, self.columns = int(self.frame), int(self.rows), int(self.columns)
        self.thickness = float(self.thickness)

    # ------------------------------------------------------------------ geometry
    @cached_property
    def normal(self) -> np.ndarray:
        """Unit plane normal, row_cosine x column_cosine (computed once per plane; read-only,
        since hot loops such as tag QC ask for it thousands of times)."""
        n = np.cross(self.row_cosine, self.column_cosine)
        n = n / np.linalg.norm(n)
        n.setflags(write=False)
        return n

    @property
    def orientation(self) -> np.ndarray:
        """ImageOrientationPatient as 6 numbers."""
        return np.concatenate([self.row_cosine, self.column_cosine])

    @property
    def affine(self) -> np.ndarray:
        """4x4 matrix mapping homogeneous (c, r, 0, 1) pixel coords to scanner mm."""
        a = np.eye(4)
        a[:3, 0] = self.row_cosine * self.pixel_spacing[1]
        a[:3, 1] = self.column_cosine * self.pixel_spacing[0]
        a[:3, 2] = self.normal
        a[:3, 3] = self.position
        return a

    @property
    def center(self) -> np.ndarray:
        """Scanner position of the image centre, mm."""
        return self.pixel_to_scanner(np.array([[(self.columns - 1) / 2, (self.rows - 1) / 2]]))[0]

    def pixel_to_scanner(self, pixels: np.ndarray) -> np.ndarray:
        """Map (n, 2) pixel coordinates (column c, row r) to (n, 3) scanner mm.

        Parameters
        ----------
        pixels : ndarray, shape (n, 2)
            Pixel coordinates (column c, row r), 0 at the first pixel's centre.

        Returns
        -------
        ndarray, shape (n, 3)
            Scanner coordinates in mm: position + c Δc row_cosine + r Δr column_cosine.
        """
        p = np.asarray(pixels, dtype=float).reshape(-1, 2)
        return (self.position
                + p[:, :1] * self.pixel_spacing[1] * self.row_cosine
                + p[:, 1:2] * self.pixel_spacing[0] * self.column_cosine)

    def scanner_to_pixel(self, points: np.ndarray) -> np.ndarray:
        """Map (n, 3) scanner mm to (n, 2) pixel coordinates (c, r), projecting onto the plane.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Scanner coordinates in mm.

        Returns
        -------
        ndarray, shape (n, 2)
            Pixel coordinates (column c, row r) of their feet on the plane (fractional).
        """
        d = np.asarray(points, dtype=float).reshape(-1, 3) - self.position
        return np.column_stack([_dot3(d, self.row_cosine) / self.pixel_spacing[1],
                                _dot3(d, self.column_cosine) / self.pixel_spacing[0]])

    def distance_to_plane(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (mm) of (n, 3) scanner points from the image plane.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Scanner coordinates in mm.

        Returns
        -------
        ndarray, shape (n,)
            Signed distance along :attr:`normal`, in mm.
        """
        return _dot3(np.asarray(points, dtype=float).reshape(-1, 3) - self.position, self.normal)

    def same_geometry(self, other: "ImagePlane", tol: float = 1e-6) -> bool:
        """True when both planes share position, orientation and spacing.

        Parameters
        ----------
        other : ImagePlane
            The plane to compare with.
        tol : float, optional
            Largest difference allowed per coordinate (mm, cosine, mm for spacing).

        Returns
        -------
        bool
            Whether position, orientation and pixel spacing agree within ``tol``.
        """
        return (np.allclose(self.position, other.position, atol=tol)
                and np.allclose(self.orientation, other.orientation, atol=tol)
                and np.allclose(self.pixel_spacing, other.pixel_spacing, atol=tol))

    def to_dict(self) -> dict:
        """JSON-safe description (the native manifest's ``images`` entries).

        Returns
        -------
        dict
            ``id, slice, view, frame, position`` (mm), ``orientation`` (6 cosines),
            ``pixel_spacing`` (mm), ``rows, columns, thickness`` (mm) and, when set,
            ``trigger_time`` (ms) and ``file``.
        """
        d = {
            "id": self.id, "slice": self.slice, "view": self.view, "frame": self.frame,
            "position": [float(x) for x in self.position],
            "orientation": [float(x) for x in self.orientation],
            "pixel_spacing": [float(x) for x in self.pixel_spacing],
            "rows": self.rows, "columns": self.columns, "thickness": self.thickness,
        }
        if self.trigger_time is not None:
            d["trigger_time"] = float(self.trigger_time)
        if self.file is not None:
            d["file"] = self.file
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ImagePlane":
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        d : dict
            A :meth:`to_dict` mapping (``rows``, ``columns``, ``thickness`` optional).

        Returns
        -------
        ImagePlane
            The plane, validated.

        Raises
        ------
        cardionurbs.errors.StudyError
            ``orientation`` is not 6 numbers, or a value fails the plane's checks.
        """
        ori = np.asarray(d["orientation"], dtype=float)
        if ori.shape != (6,):
            raise StudyError("orientation must be 6 numbers", slice=d.get("slice"),
                             frame=d.get("frame"), field="orientation")
        return cls(id=str(d["id"]), slice=str(d["slice"]), view=str(d["view"]), frame=int(d["frame"]),
                   position=d["position"], row_cosine=ori[:3], column_cosine=ori[3:],
                   pixel_spacing=tuple(d["pixel_spacing"]), rows=int(d.get("rows", 256)),
                   columns=int(d.get("columns", 256)), thickness=float(d.get("thickness", 8.0)),
                   trigger_time=d.get("trigger_time"), file=d.get("file"))
