"""Camera geometry of a specimen rotating about one axis in front of a fixed camera.

Frames and units
----------------
* **World** = specimen frame, in micrometres (µm). The rotation axis is world **x** (the larva's
  long axis, the image horizontal); the axis passes through the world origin.
* **Camera** frame: x right, y down, z along the optical axis (OpenCV convention), µm.
* **Pixels**: 0-based coordinates of the *stored* frame, i.e. the centre of the top-left pixel
  is (0, 0). A camera ROI shifts the principal point by the ROI offset; a 1-based convention
  (MATLAB, the zebrafish authors' files) differs by one pixel in x and y.

The model (``../shared/DESIGN.md``)::

    P_i = K · [R_axis | t_axis] · [Rx(ω_i) | 0]
    R_axis = Rz(pitch) · Ry(yaw)         tilt of the rotation axis
    t_axis = d · Rz(pitch) · [0, sin γ, cos γ]
                                         axis at distance d, γ moves it off-centre across its image; the
                                         origin is the axis point nearest the principal ray
                                         (:func:`axis_origin_in_camera`; for pitch ≈ 0 the paper's
                                         t_axis = d · [0, sin γ, cos γ])

θ = [yaw, pitch, γ, ω_0 … ω_{N−1}] in degrees. ω_0 is normally held at the commanded angle of
view 0 (0°): it only fixes the specimen's orientation about the axis.

Imported turntable cameras with arbitrary world frames are brought into this model by
:func:`decompose_circular`, which finds the axis from the cameras' relative rotations, the
circle of camera centres, and the similarity transform from the data's world frame to ours.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from vastcal.config import OpticsConfig, RoiConfig
from vastcal.errors import AnalysisError

log = logging.getLogger(__name__)


LENGTH_UNITS_UM: dict[str, float] = {"nm": 1e-3, "um": 1.0, "mm": 1e3, "cm": 1e4, "m": 1e6}
"""Micrometres per unit of the length units a camera world may be given in."""


def rot_x(angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about x for angles in radians; shape (..., 3, 3)."""
    a = np.asarray(angle_rad, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about y for angles in radians; shape (..., 3, 3)."""
    a = np.asarray(angle_rad, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(angle_rad: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about z for angles in radians; shape (..., 3, 3)."""
    a = np.asarray(angle_rad, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def intrinsics_from_optics(optics: OpticsConfig, roi: RoiConfig | None = None, binning: int = 1) -> np.ndarray:
    """Intrinsic matrix K (pixels, 0-based, of the stored ROI frame) from the rig's optics.

    Focal length in pixels ``f = working_distance_um · magnification / pixel_size_um`` unless
    ``focal_length_px`` is set; principal point defaults to the sensor centre
    ``((W − 1)/2, (H − 1)/2)`` and is shifted by the ROI offset.
    """
    f = optics.focal_length_px or optics.working_distance_um * optics.magnification / optics.pixel_size_um
    if optics.principal_point_px is not None:
        cx, cy = optics.principal_point_px
    else:
        cx, cy = (optics.sensor_width_px - 1) / 2.0, (optics.sensor_height_px - 1) / 2.0
    if roi is not None:
        cx, cy = cx - roi.x, cy - roi.y
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    if binning != 1:
        K[:2] /= binning
    return K


def shift_pixels(P_or_K: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """Re-express a camera (K or P, any leading shape) in pixels moved by (−dx, −dy).

    ``shift_pixels(P, 1, 1)`` converts a 1-based camera to 0-based; ``shift_pixels(P, x0, y0)``
    converts a full-sensor camera to the frame of an ROI starting at (x0, y0).
    """
    T = np.array([[1.0, 0.0, -dx], [0.0, 1.0, -dy], [0.0, 0.0, 1.0]])
    return np.einsum("ij,...jk->...ik", T, P_or_K)


@dataclass(frozen=True)
class CircularMotion:
    """Cameras of one revolution: shared K, axis tilt and placement, one roll angle per view.

    Attributes:
        K: 3×3 intrinsics in pixels of the stored frames (0-based). May be a full matrix, skew too.
        distance: distance d from the camera centre to the rotation axis, in world units (µm).
        yaw_deg, pitch_deg: axis tilt, degrees (R_axis = Rz(pitch)·Ry(yaw)).
        gamma_deg: axis placement angle γ, degrees (t_axis = d·Rz(pitch)·[0, sin γ, cos γ],
            :func:`axis_origin_in_camera`).
        rolls_deg: ω_i for every view, degrees, shape (N,).
    """

    K: np.ndarray
    distance: float
    yaw_deg: float
    pitch_deg: float
    gamma_deg: float
    rolls_deg: np.ndarray = field(repr=False)

    @property
    def n_views(self) -> int:
        """Number of views N."""
        return int(np.asarray(self.rolls_deg).shape[0])

    def theta(self) -> np.ndarray:
        """θ = [yaw, pitch, γ, ω_0 … ω_{N−1}] in degrees."""
        return np.concatenate([[self.yaw_deg, self.pitch_deg, self.gamma_deg], np.asarray(self.rolls_deg, float)])

    def with_theta(self, theta_deg: np.ndarray) -> CircularMotion:
        """A copy with θ replaced (same K and distance)."""
        th = np.asarray(theta_deg, float)
        return CircularMotion(self.K, self.distance, float(th[0]), float(th[1]), float(th[2]), th[3:].copy())

    def projection_matrices(self) -> np.ndarray:
        """P_i for every view, shape (N, 3, 4), world µm → 0-based pixels of the stored frames."""
        return projection_matrices(self.K, self.distance, self.theta()[None, :])[0]


def axis_origin_in_camera(distance: float, pitch_rad: np.ndarray, gamma_rad: np.ndarray) -> np.ndarray:
    """t (…, 3): the world origin in camera coordinates, d·Rz(pitch)·[0, sin γ, cos γ] (world units).

    The origin is the axis point nearest the camera's principal ray: t lies in the plane through the principal
    ray perpendicular to the axis image's direction (cos pitch, sin pitch) (t_x cos p + t_y sin p = 0), and γ is
    its angle from the principal ray in that plane. For the microscope (axis ≈ image rows, pitch ≈ 0) the
    origin is where the axis crosses the plane x_cam = 0 and γ tilts it along the image columns; for a turntable
    (axis ≈ image columns, pitch ≈ ±90°) γ is the axis's sideways offset — a gauge that holds for any axis
    direction not along the principal ray (a fixed x_cam = 0 has no such point when an upright axis misses the
    principal point's column).
    """
    p, g = np.asarray(pitch_rad, float), np.asarray(gamma_rad, float)
    return distance * np.stack([-np.sin(g) * np.sin(p), np.sin(g) * np.cos(p), np.cos(g)], -1)


def projection_matrices(K: np.ndarray, distance: float, theta_deg: np.ndarray) -> np.ndarray:
    """Batched P for a population of θ vectors.

    Args:
        K: 3×3 intrinsics (pixels).
        distance: axis distance d (world units, µm).
        theta_deg: (B, 3 + N) array [yaw, pitch, γ, ω_0..ω_{N−1}] in degrees.

    Returns:
        (B, N, 3, 4) projection matrices.
    """
    th = np.radians(np.atleast_2d(np.asarray(theta_deg, float)))
    yaw, pitch, gamma, rolls = th[:, 0], th[:, 1], th[:, 2], th[:, 3:]
    R_axis = rot_z(pitch) @ rot_y(yaw)  # (B,3,3)
    R = R_axis[:, None] @ rot_x(rolls)  # (B,N,3,3)
    t = axis_origin_in_camera(distance, pitch, gamma)  # (B,3)
    Rt = np.concatenate([R, np.broadcast_to(t[:, None, :, None], R.shape[:-1] + (1,))], -1)
    return np.einsum("ij,bnjk->bnik", np.asarray(K, float), Rt)


def project(P: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixel coordinates (…, M, 2) of world points (M, 3) through cameras P (…, 3, 4)."""
    X = np.concatenate([points, np.ones((points.shape[0], 1))], 1)
    x = np.einsum("...ij,mj->...mi", P, X)
    return x[..., :2] / x[..., 2:3]


def axis_probe(P: np.ndarray) -> np.ndarray:
    """Two world points (2, 3) on the rotation axis (world x), ±5 % of the camera distance from the origin.

    Probes must stay well in front of every camera, whatever the units (µm on the rig, arbitrary
    units on imported turntable data), so their length is scaled to the first camera's distance.
    """
    P0 = np.asarray(P, float).reshape(-1, 3, 4)[0]
    length = 0.05 * float(np.linalg.norm(np.linalg.solve(P0[:, :3], -P0[:, 3])))  # |camera centre|
    return np.array([[-length, 0.0, 0.0], [length, 0.0, 0.0]])


def axis_direction_px(P0: np.ndarray) -> np.ndarray:
    """Unit image direction (du, dv) of the rotation axis (world x) in view 0 of cameras P0."""
    uv = project(P0[:1], axis_probe(P0))[0]
    d = uv[1] - uv[0]
    return d / np.linalg.norm(d)


def axis_crossings(P0: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(N, L, 2): where the image of the axis crosses each scan line, for cameras P0 (N, 3, 4).

    Scan lines are columns (L = W) when the axis is closer to horizontal in view 0, rows (L = H) otherwise.
    """
    h, w = shape
    d = axis_direction_px(P0)
    horizontal = abs(d[0]) >= abs(d[1])
    pts = project(P0, axis_probe(P0))  # (N, 2, 2)
    a, b = pts[:, 0], pts[:, 1]
    out = []
    for i in range(P0.shape[0]):
        if horizontal:
            u = np.arange(w, dtype=float)
            v = a[i, 1] + (u - a[i, 0]) * (b[i, 1] - a[i, 1]) / (b[i, 0] - a[i, 0])
            out.append(np.stack([u, v], 1))
        else:
            v = np.arange(h, dtype=float)
            u = a[i, 0] + (v - a[i, 1]) * (b[i, 0] - a[i, 0]) / (b[i, 1] - a[i, 1])
            out.append(np.stack([u, v], 1))
    return np.asarray(out)


def camera_centre(P: np.ndarray) -> np.ndarray:
    """Centre (3,) of a finite camera P (3, 4): its right null vector, dehomogenised (world units)."""
    _, _, vt = np.linalg.svd(np.asarray(P, float))
    c = vt[-1]
    return c[:3] / c[3]


def decompose_projection(P: np.ndarray, front: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split P = λ·K·[R | t] into K (K[2,2] = 1), a proper rotation R (det +1) and translation t.

    P is defined up to its overall sign, and so is the side of the camera the scene is on. With ``front``
    (a world point known to be in front of the camera, e.g. the centre of a ring of cameras) the sign is
    chosen so that ``front`` has positive depth; a camera whose image axes are left-handed with respect to
    its viewing direction (det M < 0 for that sign, e.g. rows counted upwards, or a mirrored image) then
    keeps a proper R and gets the mirror in K: K's second column is negated (f_y < 0). Without ``front``
    K has a positive diagonal and the sign of P is chosen to make det R = +1 (right-handed cameras only).
    """
    P = np.asarray(P, float)
    if front is not None and float(P[2] @ np.r_[np.asarray(front, float), 1.0]) < 0:
        P = -P
    M = P[:, :3]
    # RQ decomposition through QR of the flipped, transposed matrix.
    flip = np.eye(3)[::-1]
    q, r = np.linalg.qr((flip @ M).T)
    K = flip @ r.T @ flip
    R = flip @ q.T
    S = np.diag(np.sign(np.diag(K)))
    K, R = K @ S, S @ R
    if front is not None:
        if np.linalg.det(R) < 0:  # left-handed image axes: the mirror goes into K, R stays a rotation
            F = np.diag([1.0, -1.0, 1.0])
            K, R = K @ F, F @ R
        scale = K[2, 2]
        K = K / scale
        t = np.linalg.solve(K, P[:, 3] / scale)
        return K, R, t
    scale = K[2, 2]
    K = K / scale
    t = np.linalg.solve(K, P[:, 3] / scale)
    if np.linalg.det(R) < 0:  # P was given with the opposite overall sign
        R, t = -R, -t
    return K, R, t


METRIC_SKEW = 0.005
"""Largest skew of a metric K, as a fraction of its focal length (a calibrated camera has none)."""
METRIC_ASPECT = 0.15
"""Largest departure of a metric K's pixel aspect |f_x / f_y| from 1 (analogue frame grabbers reach ~1.1)."""


def projective_intrinsics(P: np.ndarray) -> str | None:
    """Why cameras P (N, 3, 4) are projective rather than metric — the first view whose K has a skew or a pixel
    aspect no calibrated camera has (:data:`METRIC_SKEW`, :data:`METRIC_ASPECT`), in words — or None when every K
    is metric. A projective camera set (a projective reconstruction, such as the VGG turntable sequences) is a
    valid camera set: its principal point says nothing about where the images sit on a sensor."""
    for i, m in enumerate(np.asarray(P, float)):
        K = decompose_projection(m)[0]
        fx, fy, skew = float(K[0, 0]), float(K[1, 1]), float(K[0, 1])
        if abs(skew) > METRIC_SKEW * abs(fx) or abs(abs(fx / fy) - 1.0) > METRIC_ASPECT:
            return f"view {i}: K has a skew of {skew:.3g} px and focal lengths {fx:.5g} x {fy:.5g} px"
    return None


def _common_rotation_axis(Rs: np.ndarray) -> np.ndarray:
    """Unit axis (world frame) about which cameras with rotations Rs (N, 3, 3) turn, oriented so that successive
    views turn positively about it.

    Each relative rotation R_0ᵀR_i = Rot(a_i, θ_i) has the symmetric part
    (R + Rᵀ)/2 − cos θ_i·I = (1 − cos θ_i)·a_i a_iᵀ; their sum is a scatter matrix whose principal eigenvector is
    the common axis, each view weighted by 1 − cos θ_i
    (its axis is the better defined the more it turns). Unlike the antisymmetric part (2 sin θ_i·a_i), this holds at
    θ = 180°, where a view facing view 0 — every even ring of uniform steps has one — leaves sin θ = 0 and the
    antisymmetric part only its noise. The sign comes from the antisymmetric parts of the successive steps
    R_iᵀR_(i+1) (their angles are small, their sines large).

    Raises:
        AnalysisError: no relative rotation above 1°.
    """
    rel = np.einsum("ji,njk->nik", Rs[0], Rs[1:])
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    if not np.any(cos < np.cos(np.radians(1.0))):
        raise AnalysisError("the cameras do not rotate: no relative rotation above 1°")
    sym = (rel + np.transpose(rel, (0, 2, 1))) / 2.0 - cos[:, None, None] * np.eye(3)
    a = np.linalg.eigh(sym.sum(axis=0))[1][:, -1]
    steps = np.einsum("nji,njk->nik", Rs[:-1], Rs[1:])
    turn = np.stack(
        [steps[:, 2, 1] - steps[:, 1, 2], steps[:, 0, 2] - steps[:, 2, 0], steps[:, 1, 0] - steps[:, 0, 1]], 1
    )
    return -a if float(np.sum(turn @ a)) < 0 else a


CIRCULAR_FIT_WARN_PX = 1.0
"""RMS reprojection difference (px) between given cameras and their circular-motion fit above which import and
calibration warn: the model (one K, one circle of camera centres about one axis) then cannot reproduce the given
cameras to the ~1 px that silhouette edges are located to, so comparisons with those cameras are limited by it."""


def circular_fit_shortfall(rms_px: float) -> str | None:
    """What import and calibration say of given cameras that circular motion reproduces to ``rms_px`` RMS; None
    within :data:`CIRCULAR_FIT_WARN_PX`."""
    if rms_px <= CIRCULAR_FIT_WARN_PX:
        return None
    return (
        f"the imported cameras fit circular motion to {rms_px:.2f} px RMS only (per-view intrinsics or centres off one "
        f"circle): calibrated poses cannot come closer to them than that"
    )


@dataclass(frozen=True)
class CircularFit:
    """Result of :func:`decompose_circular`.

    ``world_from_data`` (4×4) maps homogeneous points of the data's world frame into the
    vastcal world frame (axis = x, origin on the axis); ``P_data ≈ P_model · world_from_data``.
    ``rms_px`` is the RMS reprojection difference between given and model cameras over a
    cloud of points around the axis, in pixels.
    """

    motion: CircularMotion
    world_from_data: np.ndarray
    rms_px: float


def decompose_circular(P: np.ndarray, check_points: np.ndarray | None = None) -> CircularFit:
    """Fit the circular-motion model to known cameras P (N, 3, 4), 0-based pixels.

    The axis direction is the common axis of the relative rotations R_0ᵀR_i (:func:`_common_rotation_axis`); its
    sign makes the roll angles increase with the view index. The origin is the axis point nearest the principal
    ray (the same point for every view of a circular motion), as the model places it (:func:`axis_origin_in_camera`),
    and view 0 gets roll 0°.

    Raises:
        AnalysisError: fewer than 3 views, views that do not rotate, or cameras that look along the axis.
    """
    P = np.asarray(P, float)
    n = P.shape[0]
    if n < 3:
        raise AnalysisError(f"need at least 3 cameras to fit circular motion, got {n}")
    # The specimen is inside the ring of cameras: their centroid is in front of every camera, which fixes
    # the sign of each P (and with it the handedness of its image axes, see decompose_projection).
    front = np.mean([camera_centre(p) for p in P], axis=0)
    Ks, Rs, ts = zip(*(decompose_projection(p, front) for p in P))
    K = np.mean(Ks, axis=0)
    Rs = np.array(Rs)
    ts = np.array(ts)
    centres = -np.einsum("nji,nj->ni", Rs, ts)

    a = _common_rotation_axis(Rs)

    # Circle centre: least squares in the plane ⟂ a (|C − c|² = r² algebraically).
    u = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    pu, pv = centres @ u, centres @ v
    A = np.stack([2 * pu, 2 * pv, np.ones(n)], 1)
    sol, *_ = np.linalg.lstsq(A, pu**2 + pv**2, rcond=None)
    c = sol[0] * u + sol[1] * v + np.mean(centres @ a) * a

    # Rotation Q' sending a to e_x, then remove the roll of view 0.
    Qp = np.stack([a, u, v])  # rows: new x, y, z
    M = Rs[0] @ Qp.T
    yaw0, pitch0, roll0 = _zyx_angles(M)
    Q = rot_x(roll0) @ Qp
    R_axis = rot_z(pitch0) @ rot_y(yaw0)
    # Origin: the axis point nearest the principal ray (axis_origin_in_camera): slide c along the axis until the
    # mean of t = R_i c + t_i has no component along the axis image's direction (cos pitch, sin pitch).
    tp = np.einsum("nij,j->ni", Rs, c) + ts
    ex_cam = R_axis[:, 0]  # the axis direction in the camera (the same in every view: it is the roll axis)
    image_dir = np.array([np.cos(pitch0), np.sin(pitch0)])
    along = float(ex_cam[:2] @ image_dir)
    if abs(along) < 1e-9:
        raise AnalysisError("the cameras look along the rotation axis: circular motion cannot be told from these views")
    c = c - float(np.mean(tp[:, :2] @ image_dir)) / along * a
    tp = np.einsum("nij,j->ni", Rs, c) + ts
    t_mean = tp.mean(axis=0)
    d = float(np.linalg.norm(t_mean))
    gamma = float(np.degrees(np.arctan2(t_mean[:2] @ np.array([-np.sin(pitch0), np.cos(pitch0)]), t_mean[2])))
    rolls = []
    for R in Rs:
        Rx_i = R_axis.T @ R @ Q.T
        rolls.append(np.degrees(np.arctan2(Rx_i[2, 1], Rx_i[1, 1])))
    rolls = np.unwrap(np.radians(rolls))
    rolls = np.degrees(rolls - rolls[0])
    if rolls[-1] < 0:
        rolls = np.where(rolls < 0, rolls + 360.0, rolls)
    motion = CircularMotion(K, d, float(np.degrees(yaw0)), float(np.degrees(pitch0)), gamma, rolls)

    world_from_data = np.eye(4)
    world_from_data[:3, :3] = Q
    world_from_data[:3, 3] = -Q @ c
    if check_points is None:
        rng = np.random.default_rng(0)
        check_points = rng.normal(scale=0.05 * d, size=(200, 3))
    data_pts = (np.linalg.inv(world_from_data) @ np.c_[check_points, np.ones(len(check_points))].T).T[:, :3]
    given = project(P, data_pts)
    model = project(motion.projection_matrices(), check_points)
    rms = float(np.sqrt(np.mean(np.sum((given - model) ** 2, -1))))
    log.info(
        "circular fit: d=%.4g yaw=%.4f° pitch=%.4f° γ=%.4f° rms=%.3g px",
        d,
        motion.yaw_deg,
        motion.pitch_deg,
        gamma,
        rms,
    )
    return CircularFit(motion, world_from_data, rms)


def _zyx_angles(M: np.ndarray) -> tuple[float, float, float]:
    """Angles (radians) with M = Rz(pitch)·Ry(yaw)·Rx(roll): returns (yaw, pitch, roll)."""
    yaw = float(np.arcsin(np.clip(-M[2, 0], -1.0, 1.0)))
    pitch = float(np.arctan2(M[1, 0], M[0, 0]))
    roll = float(np.arctan2(M[2, 1], M[2, 2]))
    return yaw, pitch, roll
