"""Conics in the image, the normalised conic C' = K^T C K, and circle pose from one conic.

A point conic is a symmetric 3x3 ``C`` with ``x^T C x = 0`` for pixels ``x = (u, v, 1)`` (pixel centres
at integer coordinates, u = column). ``C' = K^T C K`` is the cone from the camera centre through the
curve, in the OpenCV camera frame (x right, y down, z forward); normals face the camera (``n . ray < 0``).

References
----------
.. [1] D. Forsyth et al., "Invariant descriptors for 3-D object recognition and pose", IEEE TPAMI 13(10),
       1991, appendix A. https://doi.org/10.1109/34.99233
.. [2] R. Safaee-Rad et al., "Three-dimensional location estimation of circular features for machine
       vision", IEEE T-RA 8(5), 1992. https://doi.org/10.1109/70.163777
.. [3] R. Hartley, A. Zisserman, Multiple View Geometry, 2nd ed., 2003, ch. 2 and 8.
.. [4] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting", sec. 2.3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.geometry.angles import cross3
from simtest.geometry.camera import validate_intrinsics
from simtest.tolerances import TOL

__all__ = ["CirclePose", "ConeAxis", "Ellipse", "circle_pose", "conic_kind", "conic_to_ellipse", "cone_axis",
           "normalised_conic", "plane_basis", "project_circle", "section_centres"]


@dataclass(frozen=True)
class Ellipse:
    """Geometric parameters of an image ellipse.

    Attributes
    ----------
    center : ndarray of shape (2,)
        Centre (u, v) in pixels.
    semi_axes : ndarray of shape (2,)
        Semi-axes (a, b) in pixels, a >= b > 0.
    angle_rad : float
        Angle of the major axis from the +u axis toward +v, in radians, in (-pi/2, pi/2].
    """

    center: np.ndarray
    semi_axes: np.ndarray
    angle_rad: float

    def as_dict(self) -> dict:
        """JSON-ready form with the angle in degrees (interface unit)."""
        return {"center_px": [float(x) for x in self.center], "semi_axes_px": [float(x) for x in self.semi_axes],
                "angle_deg": float(np.degrees(self.angle_rad))}


@dataclass(frozen=True)
class ConeAxis:
    """Axis of the cone C' and how far the cone is from right circular.

    Attributes
    ----------
    axis : ndarray of shape (3,)
        Unit eigenvector of C' for the eigenvalue of unique sign, facing the camera (camera frame).
    eigenvalue_gap : float
        ``(l1 - l2) / (l1 - l3)`` in [0, 1) with signs normalised so that l1 >= l2 > 0 > l3: zero for a right
        circular cone, and ``sin^2`` of the angle between either circle-pose normal and the axis.
    """

    axis: np.ndarray
    eigenvalue_gap: float

    @property
    def circle_pose_tilt_deg(self) -> float:
        """Angle in degrees between the circle-pose normals and the cone axis."""
        return float(np.degrees(np.arcsin(np.sqrt(np.clip(self.eigenvalue_gap, 0.0, 1.0)))))


@dataclass(frozen=True)
class CirclePose:
    """The two solutions of the circle pose problem for one image conic.

    Attributes
    ----------
    normals : ndarray of shape (2, 3)
        N+ and N-: unit plane normals in the camera frame, facing the camera.
    centres : ndarray of shape (2, 3)
        Unit viewing directions (z > 0) of the 3D circle centre of each solution.
    """

    normals: np.ndarray
    centres: np.ndarray


def _check_conic(C, name: str = "C") -> np.ndarray:
    C = np.asarray(C, dtype=np.float64)
    if C.shape != (3, 3):
        raise ValueError(f"{name} must be a 3x3 matrix, got shape {C.shape}")
    if not np.all(np.isfinite(C)):
        raise ValueError(f"{name} has non-finite entries: {C.tolist()}")
    return 0.5 * (C + C.T)


def conic_kind(C) -> str:
    """Classify a point conic (any scale).

    Parameters
    ----------
    C : array_like of shape (3, 3)

    Returns
    -------
    str
        ``"ellipse"``, ``"imaginary"``, ``"hyperbola"``, ``"parabola"`` or ``"degenerate"`` (det C ~ 0).

    Raises
    ------
    ValueError
        If C is not 3x3 or has non-finite entries.
    """
    return _classify(_check_conic(C))[0]


def conic_to_ellipse(C) -> Ellipse | None:
    """Geometric parameters of a point conic, or None if it is not a real ellipse.

    Parameters
    ----------
    C : array_like of shape (3, 3)
        Point conic in pixel coordinates (any scale or sign).

    Returns
    -------
    Ellipse or None
        None for hyperbolas, parabolas, degenerate and imaginary conics (see :func:`conic_kind`).

    Raises
    ------
    ValueError
        If C is not 3x3 or has non-finite entries.
    """
    return _ellipse(_check_conic(C))


def normalised_conic(C, K) -> np.ndarray:
    """The normalised conic C' = K^T C K, scaled to unit Frobenius norm (paper section 2.3).

    Parameters
    ----------
    C : array_like of shape (3, 3)
        Point conic in pixel coordinates.
    K : array_like of shape (3, 3)
        Intrinsics.

    Returns
    -------
    ndarray of shape (3, 3)
        Symmetric C' in normalised camera coordinates.

    Raises
    ------
    ValueError
        If C or K is malformed or C is zero.
    """
    C = _check_conic(C)
    K = validate_intrinsics(K)
    Cn = K.T @ C @ K
    Cn = 0.5 * (Cn + Cn.T)
    norm = np.linalg.norm(Cn)
    if norm == 0:
        raise ValueError("the conic is zero")
    return Cn / norm


def cone_axis(Cn) -> ConeAxis:
    """Axis of the cone C' (eigenvector of the unique-sign eigenvalue) and the eigenvalue gap.

    For a point light at the camera centre and a plane, Phong's intensity depends only on the angle gamma
    between the ray and the normal, so each isophote is a right circular cone of axis n:
    ``C' ~ cos^2 gamma_0 I - n n^T`` (paper eq. 1, Props. 1-2). Its unique-sign eigenvector is the normal
    and the gap is 0; a gap above 0 measures the model violation (noise, curvature, light offset).

    Parameters
    ----------
    Cn : array_like of shape (3, 3)
        Normalised conic C' (any scale or sign).

    Returns
    -------
    ConeAxis

    Raises
    ------
    ValueError
        If C' is not a real elliptic cone.
    """
    w, V = _cone_eigen(Cn)
    n = V[:, 2] / np.linalg.norm(V[:, 2], axis=-1, keepdims=True)
    return ConeAxis(axis=np.where(n[2] > 0, -n, n), eigenvalue_gap=float((w[0] - w[1]) / (w[0] - w[2])))


def circle_pose(Cn) -> CirclePose:
    """Normals (and centre directions) of the two planes cutting the cone C' in a circle.

    With C' = V diag(l1, l2, l3) V^T, l1 >= l2 > 0 > l3, the normals are ``+-sin(phi) e1 + cos(phi) e3``
    with ``cos^2 phi = (l2 - l3) / (l1 - l3)`` [1, appendix A], [2]; step four of [4]. ``sin^2 phi`` is the
    eigenvalue gap g of :func:`cone_axis`, so near a right cone (g -> 0) the pose is badly conditioned.

    Parameters
    ----------
    Cn : array_like of shape (3, 3)
        Normalised conic C' (any scale or sign).

    Returns
    -------
    CirclePose
        ``normals[0]`` is N+ (``+sin phi``), ``normals[1]`` is N-; both face the camera.

    Raises
    ------
    ValueError
        If C' is not a real elliptic cone.
    """
    w, V = _cone_eigen(Cn)
    l1, l2, l3 = w
    sin_phi = np.sqrt(np.maximum(l1 - l2, 0.0) / (l1 - l3))
    cos_phi = np.sqrt(np.maximum(l2 - l3, 0.0) / (l1 - l3))
    Q = np.einsum("ij,j,lj->il", V, w, V)  # sign-normalised, unit cone
    n = np.array([[1.0], [-1.0]]) * sin_phi * V[:, 0] + cos_phi * V[:, 2]
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    c, has_centre = section_centres(np.stack([Q, Q]), n)
    if not has_centre.all():
        raise np.linalg.LinAlgError("Singular matrix")
    # facing the camera: n . c < 0 (not n_z < 0: a steep plane far off-axis faces it with n_z > 0)
    return CirclePose(normals=np.where(np.einsum("ij,ij->i", n, c)[:, None] > 0, -n, n), centres=c)


def plane_basis(normal, axes: tuple[int, int] = (0, 1)) -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal basis (u, w) of the plane perpendicular to ``normal``, ``(u, w, normal)`` right-handed.

    ``u`` is along ``normal x e[axes[0]]`` unless ``|normal[axes[0]]| >= 0.9``, then along
    ``normal x e[axes[1]]``.

    Parameters
    ----------
    normal : array_like of shape (3,) or (K, 3)
        Unit normal, or K of them.
    axes : tuple of int

    Returns
    -------
    u, w : ndarray of shape (3,) or (K, 3)
        For K normals, each row bit for bit its normal's alone.
    """
    n = np.asarray(normal, dtype=np.float64)
    first, second = axes
    if n.ndim == 2:  # (np.vecdot: np.linalg.norm's dot)
        u = cross3(n, np.where(np.abs(n[:, first:first + 1]) < 0.9, _AXES[first], _AXES[second]))
        return (u := u / np.sqrt(np.vecdot(u, u))[:, None]), cross3(n, u)
    u = cross3(n, _AXES[first if abs(n[first]) < 0.9 else second])
    return (u := u / np.linalg.norm(u)), cross3(n, u)


#: The coordinate axes as tuples (helpers of :func:`plane_basis`).
_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def _classify(C: np.ndarray) -> tuple[str, np.ndarray, np.ndarray, float]:
    """:func:`conic_kind` of a symmetric conic: ``(kind, C at unit norm, centre (2,), f0)``, NaN without a centre.

    The test is made in the frame centred on the conic's centre, so it does not depend on where the curve lies.
    """
    eps = TOL.conic_degenerate_rel
    norm = np.sqrt(np.einsum("ij,ij->", C, C))
    no_centre = (np.full(2, np.nan), np.nan)
    if norm == 0:
        return "degenerate", C, *no_centre
    C = C / norm
    lam = np.linalg.eigvalsh(C[:2, :2])
    lam_max = np.abs(lam).max()
    centre = None
    if lam_max > eps and np.abs(lam[0] * lam[1]) > eps * lam_max**2:
        try:
            centre = -np.linalg.solve(C[:2, :2], C[:2, 2])
        except np.linalg.LinAlgError:
            pass
    if centre is None:  # a parabola, or parallel lines / a line (det C ~ 0)
        sv = np.linalg.svd(C, compute_uv=False)
        return "degenerate" if sv[-1] <= eps * sv[0] else "parabola", C, *no_centre
    cross = np.einsum("i,i->", C[2, :2], centre)
    f0 = C[2, 2] + cross
    # f0 is a difference of terms of size |C22|: compare with the larger of that and the quadratic part
    if np.abs(f0) <= eps * np.maximum(lam_max, np.abs(C[2, 2]) + np.abs(cross)):
        kind = "degenerate"  # a point or two crossing lines
    elif lam[0] * lam[1] < 0:
        kind = "hyperbola"
    else:
        kind = "ellipse" if (1.0 if lam[0] > 0 else -1.0) * f0 < 0 else "imaginary"
    return kind, C, centre, f0


def _ellipse(C: np.ndarray) -> Ellipse | None:
    """:func:`conic_to_ellipse` of a symmetric conic."""
    kind, C, centre, f = _classify(C)
    if kind != "ellipse":
        return None
    if np.trace(C[:2, :2]) < 0:  # -C has the same centre and the opposite f0: A positive definite, f < 0
        C, f = -C, -f
    w, V = np.linalg.eigh(C[:2, :2])  # ascending: w[0] gives the major axis
    a = np.arctan2(V[1, 0], V[0, 0])
    a = a + np.pi if a <= -np.pi / 2 else a - np.pi if a > np.pi / 2 else a
    return Ellipse(center=centre, semi_axes=np.sqrt(-f / w), angle_rad=float(a))


def _cone_eigen(Cn) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (3,), sign-normalised to l1 >= l2 > 0 > l3, and eigenvectors (3, 3) of C' made symmetric and
    scaled to unit Frobenius norm; ValueError if it is not a real elliptic cone."""
    Cn = _check_conic(Cn, "C'")
    S = Cn / np.sqrt(np.einsum("ij,ij->", Cn, Cn))  # non-finite (with a numpy warning) for a zero cone
    finite = bool(np.isfinite(S).all())
    w, V = np.linalg.eigh(S if finite else np.eye(3))  # ascending
    eps = TOL.conic_degenerate_rel
    signs = (int(np.sum(w > eps)), int(np.sum(w < -eps)))
    if not finite or signs not in ((2, 1), (1, 2)):
        w = np.linalg.eigvalsh(Cn / np.linalg.norm(Cn))
        raise ValueError(f"C' is not a real elliptic cone: eigenvalues {w.tolist()} (need two of one sign and one of "
                         "the other)")
    if signs == (1, 2):  # -C': l3 < 0 < l2 <= l1 in ascending order
        w, V = -w[::-1], V[:, ::-1]
    return w[::-1], V[:, ::-1]


def section_centres(Q: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the sections of cones by planes through their apex' front have their centres.

    Parameters
    ----------
    Q : ndarray of shape (k, 3, 3)
        Symmetric cones (point conics of the image lifted to rays, camera frame).
    n : ndarray of shape (k, 3)
        Unit plane normals: the planes n . X = 1.

    Returns
    -------
    centres : ndarray of shape (k, 3)
        Unit directions of the sections' centres, z >= 0 (NaN where there is none).
    has_centre : ndarray of shape (k,), bool
        Where the section has a centre (its 2 x 2 quadratic part is not singular).
    """
    # the plane n.X = 1 as X = n + a u + b w, (u, w) the basis of plane_basis; the centre solves M (a, b) = g
    u, w = plane_basis(n)
    qu, qw = (Q @ u[:, :, None])[:, :, 0], (Q @ w[:, :, None])[:, :, 0]
    m00, m01, m11 = (u * qu).sum(axis=1), (u * qw).sum(axis=1), (w * qw).sum(axis=1)
    g0, g1 = (n * qu).sum(axis=1), (n * qw).sum(axis=1)
    det = m00 * m11 - m01 * m01
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (m11 * g0 - m01 * g1) / det, (m00 * g1 - m01 * g0) / det
        x = n - a[:, None] * u - b[:, None] * w
        x /= np.sqrt((x * x).sum(axis=1))[:, None]
    return x * np.where(x[:, 2] < 0, -1.0, 1.0)[:, None], det != 0


def project_circle(centre_mm, normal, radius_mm: float, K) -> np.ndarray:
    """Exact image point conic of a 3D circle, by the plane-to-image homography [3, sec. 2.3].

    Parameters
    ----------
    centre_mm : array_like of shape (3,)
        Circle centre in the camera frame, mm, z > 0.
    normal : array_like of shape (3,)
        Normal of the circle's plane (camera frame; either orientation).
    radius_mm : float
        Radius, mm, > 0.
    K : array_like of shape (3, 3)
        Intrinsics.

    Returns
    -------
    ndarray of shape (3, 3)
        ``C = H^{-T} diag(1, 1, -r^2) H^{-1}`` with ``H = K [u w c]``, unit Frobenius norm.

    Raises
    ------
    ValueError
        If the radius is not positive, the normal is zero, or the plane passes through the camera centre.
    """
    K = validate_intrinsics(K)
    c = np.asarray(centre_mm, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    if not radius_mm > 0:
        raise ValueError(f"radius_mm must be > 0, got {radius_mm}")
    nn = np.linalg.norm(n)
    if nn == 0:
        raise ValueError("normal is zero")
    n = n / nn
    if abs(n @ c) <= 1e-12 * np.linalg.norm(c):
        raise ValueError("the circle's plane passes through the camera centre: degenerate image")
    u, w = plane_basis(n)
    H = K @ np.stack([u, w, c], axis=1)
    Hinv = np.linalg.inv(H)
    C = Hinv.T @ np.diag([1.0, 1.0, -float(radius_mm) ** 2]) @ Hinv
    C = 0.5 * (C + C.T)
    return C / np.linalg.norm(C)
