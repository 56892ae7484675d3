"""Placement of the phantom heart in the scanner and its imaging planes.

The heart frame (see :mod:`cardionurbs.phantom.anatomy`) is put in scanner
(patient LPS, mm) space by a rigid map ``X = origin + R x`` whose columns
``R = [e_x e_y e_z]`` are: e_z the long axis from apex to base pointing to the
patient's right, posterior and superior (a realistic oblique orientation);
e_x toward the RV (right and anterior), orthogonalised; e_y = e_z × e_x.

Imaging planes (DICOM Image Plane module, see cardionurbs.imaging.geometry):

* SA stack: planes z = h_k ⟂ long axis, numbered from base (``sa_00``) to
  apex, the first ``first_offset_mm`` below the ED base (0.6 × the spacing unless
  ``sa_first_offset_mm`` is given: a planner puts the first slice within one gap of the
  valve plane, so every slab of the stack cuts the ventricle), then every
  ``sa_spacing_mm`` while the ED LV cavity is still cut (h >= z_endo_apex + 3 mm).
  Row cosine at ``sa_rotation_deg`` about e_z from −e_x (RV on the image left),
  column cosine e_z × row, so the plane normal is +e_z.
* LA views through the long axis: 4-chamber (azimuth 0°, through the RV),
  2-chamber (90°) and 3-chamber (135°); row cosine the radial direction
  u = cos α e_x + sin α e_y, column cosine −e_z (base at the top).
* 256 × 256 matrix, 300 mm field of view (pixel 1.171875 mm), images centred
  near the heart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cardionurbs.errors import PhantomError
from cardionurbs.imaging.geometry import ImagePlane
from cardionurbs.phantom.anatomy import Anatomy

LA_VIEWS = {"la_4ch": 0.0, "la_2ch": 90.0, "la_3ch": 135.0}
# first SA slice below the ED base, as a share of the slice spacing (6 mm at 10 mm slices)
FIRST_OFFSET_SHARE = 0.6


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class HeartPose:
    """Placement of the heart frame in scanner coordinates (LPS, mm): a rigid map, preceded for a
    realistic anatomy by the volume-preserving apex bend x ↦ x + d(z) of
    :mod:`cardionurbs.phantom.shape` (``bend``, with the base height ``z_base`` it tapers to).

    Attributes
    ----------
    origin : ndarray, shape (3,)
        The heart frame's origin (the epicardial apex) in scanner coordinates, mm.
    rotation : ndarray, shape (3, 3)
        Columns e_x (toward the RV), e_y, e_z (apex to base) in scanner coordinates.
    bend : cardionurbs.phantom.shape.ShapeModes or None
        Shape modes with an apex shift, or None.
    z_base : float
        The base height the bend tapers to, mm.
    """

    origin: np.ndarray
    rotation: np.ndarray     # 3x3, columns e_x, e_y, e_z in scanner coordinates
    bend: object = None      # ShapeModes with an apex shift, or None
    z_base: float = 0.0

    def _bend(self, p: np.ndarray, sign: float) -> np.ndarray:
        return p if self.bend is None else self.bend.displace(p, self.z_base, sign)

    def unbend(self, points: np.ndarray) -> np.ndarray:
        """Realistic heart-frame positions -> the unbent (motion) frame; identity when ideal.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Realistic heart-frame positions, mm.

        Returns
        -------
        ndarray, shape (n, 3)
            Motion-frame positions, mm.
        """
        return self._bend(np.asarray(points, dtype=float).reshape(-1, 3), -1.0)

    def bent(self, points: np.ndarray) -> np.ndarray:
        """The motion frame -> realistic heart-frame positions (the apex bend); identity when ideal.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Motion-frame positions, mm.

        Returns
        -------
        ndarray, shape (n, 3)
            Realistic heart-frame positions, mm.
        """
        return self._bend(np.asarray(points, dtype=float).reshape(-1, 3), 1.0)

    def rigid_to_scanner(self, points: np.ndarray) -> np.ndarray:
        """The rigid part alone: heart-frame points (no bend) -> scanner mm.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Heart-frame points, mm.

        Returns
        -------
        ndarray, shape (n, 3)
            origin + R p, scanner mm.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        return self.origin + p @ self.rotation.T

    @classmethod
    def default(cls, z_base: float, long_axis=(-0.55, 0.42, 0.72), rv_direction=(-0.45, -0.85, 0.05),
                mitral_center=(4.0, -12.0, 18.0), bend=None) -> "HeartPose":
        """Realistic oblique pose: long axis right-posterior-superior, RV right-anterior.

        Parameters
        ----------
        z_base : float
            The base height, mm.
        long_axis : sequence of float, optional
            The long axis (apex to base) in scanner coordinates (normalised).
        rv_direction : sequence of float, optional
            The direction toward the RV (made perpendicular to the axis).
        mitral_center : sequence of float, optional
            The mitral centre in scanner coordinates, mm.
        bend : cardionurbs.phantom.shape.ShapeModes or None, optional
            Shape modes with an apex shift.

        Returns
        -------
        HeartPose
            The pose.
        """
        ez = _unit(long_axis)
        ex = _unit(np.asarray(rv_direction, dtype=float) - np.dot(rv_direction, ez) * ez)
        ey = np.cross(ez, ex)
        rot = np.column_stack([ex, ey, ez])
        origin = np.asarray(mitral_center, dtype=float) - z_base * ez
        return cls(origin=origin, rotation=rot, bend=bend, z_base=float(z_base))

    def to_scanner(self, points: np.ndarray) -> np.ndarray:
        """Motion-frame heart points (as the annotation computes them) -> scanner mm.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Motion-frame heart points, mm.

        Returns
        -------
        ndarray, shape (n, 3)
            Scanner coordinates, mm.
        """
        return self.rigid_to_scanner(self.bent(points))

    def to_heart(self, points: np.ndarray) -> np.ndarray:
        """Scanner mm -> motion-frame heart points (the bend undone).

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Scanner coordinates, mm.

        Returns
        -------
        ndarray, shape (n, 3)
            Motion-frame heart points, mm.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        return self.unbend((p - self.origin) @ self.rotation)

    def direction_to_scanner(self, v: np.ndarray) -> np.ndarray:
        """A heart-frame direction in scanner axes (rotation only).

        Parameters
        ----------
        v : ndarray, shape (3,) or (n, 3)
            Heart-frame direction(s).

        Returns
        -------
        ndarray
            R v, same shape.
        """
        return np.asarray(v, dtype=float) @ self.rotation.T

    def to_dict(self) -> dict:
        """JSON-safe pose (truth.json ``pose``).

        Returns
        -------
        dict
            ``origin_mm``, ``axes`` (``x_to_rv``, ``y``, ``z_apex_to_base``) and, with a bend,
            ``apex_shift_mm``.
        """
        bend = {} if self.bend is None else {"apex_shift_mm": [float(v) for v in self.bend.apex_shift_mm]}
        return {**bend, "origin_mm": [float(v) for v in self.origin],
                "axes": {"x_to_rv": [float(v) for v in self.rotation[:, 0]],
                         "y": [float(v) for v in self.rotation[:, 1]],
                         "z_apex_to_base": [float(v) for v in self.rotation[:, 2]]}}


@dataclass(frozen=True)
class SliceSpec:
    """One imaging location: id, view, heart-frame plane (centre, row, column directions).

    Attributes
    ----------
    id : str
        The slice id (``sa_00`` base ..., ``la_2ch``, ``la_3ch``, ``la_4ch``, ``la_rvot``).
    view : str
        ``"SA"`` or ``"LA"``.
    center : ndarray, shape (3,)
        The plane's centre, heart frame, mm.
    row, column : ndarray, shape (3,)
        The image row and column directions, heart-frame unit vectors.
    height : float or None
        SA: the plane height z = h, mm.
    azimuth : float or None
        LA: the view's azimuth α, rad.
    normal : ndarray, shape (3,)
        row × column.
    """

    id: str
    view: str
    center: np.ndarray        # heart frame, mm
    row: np.ndarray           # heart frame unit vector
    column: np.ndarray        # heart frame unit vector
    height: float | None = None      # SA: plane height z = h, mm
    azimuth: float | None = None     # LA: α, radians

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.row, self.column)


@dataclass(frozen=True)
class Acquisition:
    """Imaging protocol: matrix, field of view, SA spacing/thickness. ``sa_first_offset_mm``
    (None: ``FIRST_OFFSET_SHARE`` × ``sa_spacing_mm``) is how far the first SA slice lies below
    the ED base.

    Attributes
    ----------
    rows, columns : int
        Image matrix, at least 32 each.
    fov_mm : float
        Field of view along the longer matrix side, mm.
    sa_spacing_mm, sa_thickness_mm : float
        SA slice spacing and thickness, mm.
    la_thickness_mm : float
        LA slice thickness, mm.
    sa_first_offset_mm : float or None
        First SA slice below the ED base, mm (None: :data:`FIRST_OFFSET_SHARE` × spacing).
    sa_rotation_deg : float
        The SA row direction's rotation about e_z, degrees.
    n_sa : int or None
        SA slices (None: base to apex), at least 2.
    first_offset_mm : float
        The first SA slice's distance below the ED base, mm.
    pixel_mm : float
        Pixel size, mm (square pixels).

    Raises
    ------
    cardionurbs.errors.PhantomError
        A length not positive, a matrix under 32, ``n_sa`` < 2 or a negative first offset.
    """

    rows: int = 256
    columns: int = 256
    fov_mm: float = 300.0
    sa_spacing_mm: float = 10.0
    sa_thickness_mm: float = 8.0
    la_thickness_mm: float = 8.0
    sa_first_offset_mm: float | None = None
    sa_rotation_deg: float = 20.0
    n_sa: int | None = None

    def __post_init__(self) -> None:
        for name in ("fov_mm", "sa_spacing_mm", "sa_thickness_mm", "la_thickness_mm"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise PhantomError(f"{name} must be positive, got {v!r}")
        if self.rows < 32 or self.columns < 32:
            raise PhantomError("image matrix must be at least 32 x 32")
        if self.n_sa is not None and self.n_sa < 2:
            raise PhantomError(f"n_sa must be >= 2, got {self.n_sa!r}")
        off = self.sa_first_offset_mm
        if off is not None and not (np.isfinite(off) and off >= 0):
            raise PhantomError(f"sa_first_offset_mm must be >= 0, got {off!r}")

    @property
    def first_offset_mm(self) -> float:
        """Distance (mm) of the first SA slice below the ED base plane."""
        if self.sa_first_offset_mm is not None:
            return float(self.sa_first_offset_mm)
        return FIRST_OFFSET_SHARE * self.sa_spacing_mm

    @property
    def pixel_mm(self) -> float:
        return self.fov_mm / max(self.rows, self.columns)


def sa_heights(anatomy: Anatomy, acq: Acquisition) -> np.ndarray:
    """Heights h_k (mm above the apex) of the SA slices, base to apex (the first one
    ``acq.first_offset_mm`` below the base plane, or below the lowest point of a saddle annulus).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy.
    acq : Acquisition
        The protocol.

    Returns
    -------
    ndarray, shape (k,)
        The heights h_k, mm, base to apex.

    Raises
    ------
    cardionurbs.errors.PhantomError
        The stack would reach beyond the apex.
    """
    top = min(anatomy.z_base - acq.first_offset_mm, anatomy.z_top_min - 2.0)
    if acq.n_sa is not None:
        h = top - acq.sa_spacing_mm * np.arange(acq.n_sa)
    else:
        n = int(np.floor((top - (anatomy.z_endo_apex + 3.0)) / acq.sa_spacing_mm)) + 1
        h = top - acq.sa_spacing_mm * np.arange(max(n, 2))
    if h[-1] <= 0:
        raise PhantomError(f"the SA stack ({len(h)} slices, spacing {acq.sa_spacing_mm:g} mm) "
                           "extends beyond the apex")
    return h


def slice_specs(anatomy: Anatomy, acq: Acquisition) -> list[SliceSpec]:
    """SA stack (base to apex) then the 2-, 3- and 4-chamber LA views (heart frame).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy.
    acq : Acquisition
        The protocol.

    Returns
    -------
    list of SliceSpec
        The SA slices (outlet slices first when the anatomy has outflow tracts), then the LA
        views.
    """
    out = []
    g = np.radians(acq.sa_rotation_deg)
    row = np.array([-np.cos(g), -np.sin(g), 0.0])
    col = np.cross([0.0, 0.0, 1.0], row)
    heights = sa_heights(anatomy, acq)
    if anatomy.outflow is not None:
        heights = np.r_[outlet_heights(anatomy, heights[0], acq.sa_spacing_mm), heights]
    for k, h in enumerate(heights):
        out.append(SliceSpec(f"sa_{k:02d}", "SA", np.array([12.0, 0.0, h]), row, col, height=float(h)))
    for name in ("la_2ch", "la_3ch", "la_4ch"):
        out.append(la_plane(anatomy, name))
    if anatomy.outflow is not None:
        out.append(la_plane(anatomy, "la_rvot"))
    return out


def outlet_heights(anatomy: Anatomy, top: float, spacing: float) -> np.ndarray:
    """SA heights above the stack's top slice that cut the RV outflow tract wholly below the
    pulmonary valve at ED (the stack continued at its spacing, with no slot left out: a
    slice within 1 mm of the base, where the stack's top is held below a saddle annulus,
    is one of them), highest first.

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        An anatomy with outflow tracts.
    top : float
        The stack's top slice height, mm.
    spacing : float
        The SA spacing, mm.

    Returns
    -------
    ndarray
        The heights, mm, highest first.
    """
    from cardionurbs.phantom.outflow import pulmonary_ring
    z_valve = float(pulmonary_ring(anatomy)[:, 2].min()) - 1.0
    h = top + spacing * np.arange(1, 20)
    # every slot up to the valve: one left out (once ``h > z_base + 1``) made the stack
    # uneven, and a NIfTI stack of one spacing misplaced every slice beyond the gap
    return h[h < z_valve][::-1]


def la_plane(anatomy: Anatomy, name: str) -> SliceSpec:
    """One LA view (heart frame). The 2-, 3- and 4-chamber views are planned as a radiographer
    would: through the (bent) ED apex and the mitral centre at their azimuths. ``la_rvot`` (an
    anatomy with outflow tracts) contains the LV axis and the RVOT centreline: the plane through
    the axis at the tract's azimuth α (the bend is zero above the base).

    Parameters
    ----------
    anatomy : cardionurbs.phantom.anatomy.Anatomy
        The solved anatomy.
    name : str
        ``"la_2ch"``, ``"la_3ch"``, ``"la_4ch"`` or ``"la_rvot"``.

    Returns
    -------
    SliceSpec
        The view.
    """
    if name == "la_rvot":
        from cardionurbs.phantom.outflow import rvot_frame
        a = rvot_frame(anatomy).alpha
        u = np.array([np.cos(a), np.sin(a), 0.0])
        centre = np.array([0.0, 0.0, 0.6 * anatomy.z_base]) + 25.0 * u
        return SliceSpec(name, "LA", centre, u, np.array([0.0, 0.0, -1.0]), azimuth=float(a))
    shape = anatomy.shape
    apex = np.zeros(3)
    axis = np.array([0.0, 0.0, 1.0])
    if shape is not None and shape.bends:
        # planned as a radiographer would: through the (bent) ED apex and the mitral centre
        apex = np.r_[shape.apex_shift(0.0, anatomy.z_base)[0], 0.0]
        axis = np.array([0.0, 0.0, anatomy.z_base]) - apex
        axis = axis / np.linalg.norm(axis)
    a = np.radians(LA_VIEWS[name])
    u = np.array([np.cos(a), np.sin(a), 0.0])
    u = u - (u @ axis) * axis
    u = u / np.linalg.norm(u)
    centre = apex + 0.55 * anatomy.z_base / axis[2] * axis + 10.0 * u
    return SliceSpec(name, "LA", centre, u, -axis, azimuth=float(a))


def image_plane(spec: SliceSpec, pose: HeartPose, acq: Acquisition, frame: int, image_id: str,
                trigger_time: float | None, file: str | None = None) -> ImagePlane:
    """The DICOM geometry of one slice at one frame (ImagePositionPatient = first pixel centre).

    Parameters
    ----------
    spec : SliceSpec
        The slice.
    pose : HeartPose
        Heart frame -> scanner.
    acq : Acquisition
        The protocol (matrix, pixel size, thicknesses).
    frame : int
        The frame index, 0-based.
    image_id : str
        The image's id (its SOPInstanceUID).
    trigger_time : float or None
        Its trigger time, ms.
    file : str or None, optional
        Its file, relative to the study folder.

    Returns
    -------
    cardionurbs.imaging.geometry.ImagePlane
        The image plane, scanner mm.
    """
    px = acq.pixel_mm
    row = pose.direction_to_scanner(spec.row)
    col = pose.direction_to_scanner(spec.column)
    centre = pose.rigid_to_scanner(spec.center)[0]
    position = centre - 0.5 * (acq.columns - 1) * px * row - 0.5 * (acq.rows - 1) * px * col
    thick = acq.sa_thickness_mm if spec.view == "SA" else acq.la_thickness_mm
    return ImagePlane(id=image_id, slice=spec.id, view=spec.view, frame=frame, position=position,
                      row_cosine=row, column_cosine=col, pixel_spacing=(px, px), rows=acq.rows,
                      columns=acq.columns, thickness=thick, trigger_time=trigger_time, file=file)
