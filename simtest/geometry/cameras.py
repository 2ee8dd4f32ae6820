"""Camera models: pixel <-> unit viewing ray in the camera frame, and their Jacobians.

OpenCV camera frame (x right, y down, z forward), pixel centres at integers, (u, v) = (column, row).
Each model maps pixels (N, 2) to unit rays (N, 3) and back, with Jacobians d(ray)/d(u, v) (N, 3, 2) and
d(u, v)/d(ray) (N, 2, 3); points outside a model's domain give NaN rows, never an exception. The Jacobians
are tied by ``[J_P; d^T] [J_R | d] = I_3`` at a unit ray d: each model implements one, the base class the other.

References
----------
.. [1] D. Scaramuzza, A. Martinelli, R. Siegwart, "A toolbox for easily calibrating omnidirectional
   cameras", IROS 2006, doi:10.1109/IROS.2006.282372.
.. [2] J. Kannala, S. S. Brandt, "A generic camera model and calibration method for conventional,
   wide-angle, and fish-eye lenses", IEEE TPAMI 28(8), 2006, doi:10.1109/TPAMI.2006.153.
.. [3] T. L. Bobrow et al., "Colonoscopy 3D video dataset with paired depth from 2D-3D registration",
   Medical Image Analysis 90, 2023, doi:10.1016/j.media.2023.102956.
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from typing import ClassVar

import cv2
import numpy as np

from simtest._checks import finite_number
from simtest.geometry.camera import IntrinsicsError, validate_intrinsics

__all__ = ["CameraModel", "FisheyeCamera", "OmnidirectionalCamera", "PinholeCamera", "c3vd_camera"]

#: Newton iterations stop when the pixel residual is below this (px)
_NEWTON_PX = 1e-9
_NEWTON_MAX_IT = 60


def _as_rows(x, width: int, what: str) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != width:
        raise ValueError(f"{what} must have shape (N, {width}), got {x.shape}")
    return x


_as_uv = functools.partial(_as_rows, width=2, what="pixels")
_as_rays = functools.partial(_as_rows, width=3, what="rays")


def _image_size(size, where: str) -> tuple[int, int] | None:
    if size is None:
        return None
    if len(size) != 2 or any(isinstance(s, bool) or not isinstance(s, (int, np.integer)) for s in size) \
            or min(size) <= 0:
        raise IntrinsicsError(f"{where}: image_size must be [W, H] positive integers, got {list(size)!r}")
    return int(size[0]), int(size[1])



def _linear_rows(xy: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``xy @ M.T`` for (N, 2) points, element by element, so each row's bits do not depend on N."""
    x, y = xy[:, 0], xy[:, 1]
    return np.stack([M[0, 0] * x + M[0, 1] * y, M[1, 0] * x + M[1, 1] * y], axis=1)


def _affine_rows(uv: np.ndarray, Kinv: np.ndarray) -> np.ndarray:
    """First two coordinates of ``Kinv (u, v, 1)`` for (N, 2) pixels, element by element."""
    u, v = uv[:, 0], uv[:, 1]
    return np.stack([Kinv[0, 0] * u + Kinv[0, 1] * v + Kinv[0, 2],
                     Kinv[1, 0] * u + Kinv[1, 1] * v + Kinv[1, 2]], axis=1)

def _inv(M: np.ndarray) -> np.ndarray:
    """Inverses of the (N, 3, 3) matrices ``M``; NaN where a matrix is not finite."""
    out = np.full(M.shape, np.nan)
    ok = np.all(np.isfinite(M), axis=(1, 2))
    out[ok] = np.linalg.inv(M[ok])
    return out


class CameraModel(ABC):
    """A central camera: pixels <-> unit viewing rays through the camera centre.

    Attributes
    ----------
    image_size : tuple of int (W, H) or None
        Image size in pixels, when known.
    model : str
        The camera file's ``"model"`` name.
    """

    model: ClassVar[str] = ""
    image_size: tuple[int, int] | None

    @abstractmethod
    def pixel_to_ray(self, uv) -> np.ndarray:
        """Unit viewing rays of pixels.

        Parameters
        ----------
        uv : array_like of shape (N, 2)
            Pixel coordinates (u, v), pixel centres at integers.

        Returns
        -------
        ndarray of shape (N, 3)
            Unit rays in the camera frame; NaN rows outside the model's domain.
        """

    @abstractmethod
    def ray_to_pixel(self, rays) -> np.ndarray:
        """Pixels of viewing rays.

        Parameters
        ----------
        rays : array_like of shape (N, 3)
            Directions in the camera frame, any positive length.

        Returns
        -------
        ndarray of shape (N, 2)
            Pixel coordinates (u, v); NaN rows for rays the model cannot image.
        """

    @property
    def principal_point(self) -> np.ndarray:
        """ndarray of shape (2,): the pixel of the optical axis +z (that of ``K`` unless a model says otherwise)."""
        return self.K[:2, 2].copy()

    @abstractmethod
    def params(self) -> dict:
        """The model's parameters as the camera file writes them (without ``model``/``image_size``)."""

    def pixel_to_ray_jacobian(self, uv) -> np.ndarray:
        """d(unit ray)/d(u, v) at pixels.

        Parameters
        ----------
        uv : array_like of shape (N, 2)
            Pixels.

        Returns
        -------
        ndarray of shape (N, 3, 2)
            Jacobians, per pixel, of :meth:`pixel_to_ray`; each is orthogonal to its ray.
        """
        uv = _as_uv(uv)
        d = self.pixel_to_ray(uv)
        JP = self._ray_to_pixel_jacobian_unit(d)
        return _inv(np.concatenate([JP, d[:, None, :]], axis=1))[:, :, :2]  # inverse of [J_P; d^T]

    def ray_to_pixel_jacobian(self, rays) -> np.ndarray:
        """d(u, v)/d(ray) at rays.

        Parameters
        ----------
        rays : array_like of shape (N, 3)
            Directions, any positive length.

        Returns
        -------
        ndarray of shape (N, 2, 3)
            Jacobians of :meth:`ray_to_pixel`; each annihilates its ray (scale invariance).
        """
        rays = _as_rays(rays)
        n = np.linalg.norm(rays, axis=1)
        d = rays / n[:, None]
        return self._ray_to_pixel_jacobian_unit(d) / n[:, None, None]

    def _ray_to_pixel_jacobian_unit(self, d: np.ndarray) -> np.ndarray:
        """d(pixel)/d(ray) at unit rays d (N, 3); default from a model's own :meth:`pixel_to_ray_jacobian`."""
        uv = self.ray_to_pixel(d)
        JR = self.pixel_to_ray_jacobian(uv)
        return _inv(np.concatenate([JR, d[:, :, None]], axis=2))[:, :2, :]  # inverse of [J_R | d]

    def to_json_dict(self) -> dict:
        """The camera file's JSON object for this model (without lights)."""
        d = {"model": self.model, **self.params()}
        d["image_size"] = None if self.image_size is None else [int(s) for s in self.image_size]
        return d

    def __eq__(self, other) -> bool:
        return self.to_json_dict() == other.to_json_dict() if type(self) is type(other) else NotImplemented

    def __hash__(self) -> int:
        return hash(repr(self.to_json_dict()))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.to_json_dict()!r})"


def _parse_dist(value, where: str) -> np.ndarray | None:
    if value is None:
        return None
    if isinstance(value, (list, tuple)) and any(isinstance(x, bool) for x in value):
        raise IntrinsicsError(f"{where}: must be a list of numbers, got {value!r}")
    try:
        d = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise IntrinsicsError(f"{where}: must be a list of numbers, got {value!r}") from None
    if d.size not in (0, 4, 5, 8, 12, 14):
        raise IntrinsicsError(f"{where}: OpenCV needs 4, 5, 8, 12 or 14 coefficients, got {d.size}")
    if not np.all(np.isfinite(d)):
        raise IntrinsicsError(f"{where}: has non-finite entries")
    if d.size == 14 and np.any(d[12:] != 0):
        raise IntrinsicsError(f"{where}: tilted-sensor coefficients (tauX, tauY) are not supported, got {d[12:].tolist()}")
    return d if d.size and np.any(d != 0) else None


class PinholeCamera(CameraModel):
    """Pinhole intrinsics K with OpenCV's lens distortion (``cv2.projectPoints`` with rvec = tvec = 0).

    The inverse is Newton's method on the distortion, started from ``cv2.undistortPoints``, to 1e-9 px.
    Rays with Z <= 0 have no pixel (NaN).

    Parameters
    ----------
    K : array_like of shape (3, 3)
        ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``, pixels.
    dist_coeffs : array_like of shape (4,), (5,), (8,), (12,) or (14,), or None
        OpenCV order (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tauX, tauY]]]]); tilt coefficients
        must be zero. None or all zeros: no distortion.
    image_size : (W, H) or None

    Raises
    ------
    IntrinsicsError
        Invalid K, coefficients or size.
    """

    model = "pinhole"

    def __init__(self, K, dist_coeffs=None, image_size=None):
        # the model's own read-only copies: the caller's arrays stay theirs, writable
        self.K = validate_intrinsics(K).copy()
        self.K.setflags(write=False)
        self.dist_coeffs = _parse_dist(dist_coeffs, "dist_coeffs")
        if self.dist_coeffs is not None:
            self.dist_coeffs = self.dist_coeffs.copy()
            self.dist_coeffs.setflags(write=False)
        self.image_size = _image_size(image_size, "PinholeCamera")
        dc = np.zeros(0) if self.dist_coeffs is None else self.dist_coeffs[:12]
        self._k = np.pad(dc, (0, 12 - dc.size))  # k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4
        self._Kinv = np.linalg.inv(self.K)

    def params(self) -> dict:
        return {"K": self.K.tolist(),
                "dist_coeffs": None if self.dist_coeffs is None else [float(x) for x in self.dist_coeffs]}

    def _distort(self, x: np.ndarray, y: np.ndarray, jac: bool = False):
        k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = self._k
        r2 = x * x + y * y
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        R = num / den
        xd = x * R + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r2 * r2
        yd = y * R + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r2 * r2
        if not jac:
            return xd, yd
        dnum = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        dden = k4 + r2 * (2 * k5 + 3 * k6 * r2)
        dR = (dnum * den - num * dden) / (den * den)  # dR/d(r^2)
        sx = s1 + 2 * s2 * r2
        sy = s3 + 2 * s4 * r2
        J = np.empty(x.shape + (2, 2))
        J[..., 0, 0] = R + 2 * x * x * dR + 2 * p1 * y + 6 * p2 * x + 2 * x * sx
        J[..., 0, 1] = 2 * x * y * dR + 2 * p1 * x + 2 * p2 * y + 2 * y * sx
        J[..., 1, 0] = 2 * x * y * dR + 2 * p1 * x + 2 * p2 * y + 2 * x * sy
        J[..., 1, 1] = R + 2 * y * y * dR + 6 * p1 * y + 2 * p2 * x + 2 * y * sy
        return xd, yd, J

    def ray_to_pixel(self, rays) -> np.ndarray:
        rays = _as_rays(rays)
        with np.errstate(divide="ignore", invalid="ignore"):
            Z = np.where(rays[:, 2] > 0, rays[:, 2], np.nan)
            x, y = rays[:, 0] / Z, rays[:, 1] / Z
        xd, yd = self._distort(x, y)
        K = self.K
        return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)

    def _ray_to_pixel_jacobian_unit(self, d: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            Z = np.where(d[:, 2] > 0, d[:, 2], np.nan)
            x, y = d[:, 0] / Z, d[:, 1] / Z
        _, _, JD = self._distort(x, y, jac=True)
        Jx = np.zeros((len(d), 2, 3))  # d(x, y)/d(X, Y, Z)
        Jx[:, 0, 0] = 1 / Z
        Jx[:, 0, 2] = -x / Z
        Jx[:, 1, 1] = 1 / Z
        Jx[:, 1, 2] = -y / Z
        return self.K[:2, :2] @ JD @ Jx

    def pixel_to_ray(self, uv) -> np.ndarray:
        uv = _as_uv(uv)
        K = self.K
        xyd = _affine_rows(uv, self._Kinv)
        if self.dist_coeffs is None or len(uv) == 0:
            xy = xyd
        else:
            crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-12)
            start = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, self.dist_coeffs, criteria=crit).reshape(-1, 2)
            xy = np.where(np.isfinite(start), start, xyd)
            fpx = max(K[0, 0], K[1, 1])
            done = np.zeros(len(uv), dtype=bool)
            for _ in range(_NEWTON_MAX_IT):
                xd, yd, J = self._distort(xy[:, 0], xy[:, 1], jac=True)
                res = np.stack([xd, yd], axis=1) - xyd
                done = np.abs(res).max(axis=1) * fpx < _NEWTON_PX
                if done.all():
                    break
                with np.errstate(all="ignore"):
                    step = np.linalg.solve(J[~done], res[~done, :, None])[..., 0]
                xy[~done] -= step
            xy[~done] = np.nan
        rays = np.concatenate([xy, np.ones((len(uv), 1))], axis=1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


class FisheyeCamera(CameraModel):
    """OpenCV's fisheye model (Kannala-Brandt [2]_), extended past 90 deg by theta = atan2(|(X, Y)|, Z).

    theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8); the inverse is Newton's method
    on the branch where theta_d grows; pixels beyond it have no ray (NaN).

    Parameters
    ----------
    K : array_like of shape (3, 3)
        ``[[fx, fx * alpha, cx], [0, fy, cy], [0, 0, 1]]``, pixels.
    D : array_like of shape (4,)
        k1, k2, k3, k4.
    image_size : (W, H) or None
        When given, the model must be invertible over the whole frame.

    Raises
    ------
    IntrinsicsError
        Invalid K, D or size, or a D not invertible over the frame.
    """

    model = "fisheye"

    def __init__(self, K, D, image_size=None):
        self.K = validate_intrinsics(K).copy()  # the model's own read-only copies (as PinholeCamera)
        self.K.setflags(write=False)
        if isinstance(D, (list, tuple)) and any(isinstance(x, bool) for x in D):
            raise IntrinsicsError(f"D: must be 4 numbers, got {D!r}")
        try:
            D = np.asarray(D, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise IntrinsicsError(f"D: must be 4 numbers, got {D!r}") from None
        if D.size != 4 or not np.all(np.isfinite(D)):
            raise IntrinsicsError(f"D: must be 4 finite numbers [k1, k2, k3, k4], got {D.tolist()}")
        self.D = D.copy()
        self.D.setflags(write=False)
        self.image_size = _image_size(image_size, "FisheyeCamera")
        self._Kinv = np.linalg.inv(self.K)
        # the invertible part of theta_d(theta) on [0, 180 deg]: up to its first turn
        theta = np.linspace(0.0, np.pi, 20001)
        td = self._theta_d(theta)
        turn = np.flatnonzero(np.diff(td) <= 0)
        k = int(turn[0]) + 1 if len(turn) else len(theta)
        self._table_theta, self._table_td = theta[:k], td[:k]
        if self.image_size is not None:
            W, H = self.image_size
            corners = np.array([[0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1]], dtype=np.float64)
            xy = (np.concatenate([corners, np.ones((4, 1))], axis=1) @ self._Kinv.T)[:, :2]
            rmax = np.linalg.norm(xy, axis=1).max()
            if rmax > self._table_td[-1]:
                raise IntrinsicsError(f"D: not invertible over the frame (its corners are {rmax:.3g} focal "
                                      f"lengths off the centre; the image radius stops growing at "
                                      f"{self._table_td[-1]:.3g}, {np.degrees(self._table_theta[-1]):.1f} "
                                      "deg off the axis)")

    def _theta_d(self, theta, deriv: bool = False):
        k1, k2, k3, k4 = self.D
        t2 = theta * theta
        poly = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
        if not deriv:
            return theta * poly
        dpoly = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        return theta * poly, dpoly

    def params(self) -> dict:
        return {"K": self.K.tolist(), "D": [float(x) for x in self.D]}

    def ray_to_pixel(self, rays) -> np.ndarray:
        rays = _as_rays(rays)
        rho = np.hypot(rays[:, 0], rays[:, 1])
        theta = np.arctan2(rho, rays[:, 2])
        td = self._theta_d(theta)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(rho > 0, td / rho, 0.0)
        xd, yd = s * rays[:, 0], s * rays[:, 1]
        K = self.K
        out = np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)
        out[~np.all(np.isfinite(rays), axis=1) | (np.linalg.norm(rays, axis=1) == 0)] = np.nan
        return out

    def _ray_to_pixel_jacobian_unit(self, d: np.ndarray) -> np.ndarray:
        X, Y, Z = d[:, 0], d[:, 1], d[:, 2]
        rho = np.hypot(X, Y)
        theta = np.arctan2(rho, Z)
        td, dtd = self._theta_d(theta, deriv=True)
        small = rho < 1e-12
        rs = np.where(small, 1.0, rho)
        n2 = rho * rho + Z * Z
        # theta = atan2(rho, Z): dtheta = (Z drho - rho dZ) / n2, drho = (X dX + Y dY) / rho
        dtheta = np.stack([Z * X / rs / n2, Z * Y / rs / n2, -rho / n2], axis=1)
        drho = np.stack([X / rs, Y / rs, np.zeros_like(X)], axis=1)
        s = td / rs  # x' = s X, y' = s Y
        ds = (dtd / rs)[:, None] * dtheta - (td / rs**2)[:, None] * drho
        J = np.empty((len(d), 2, 3))
        J[:, 0, :] = X[:, None] * ds
        J[:, 1, :] = Y[:, None] * ds
        J[:, 0, 0] += s
        J[:, 1, 1] += s
        # On the axis: x' = X / Z to first order.
        if small.any():
            J[small] = 0.0
            J[small, 0, 0] = 1 / Z[small]
            J[small, 1, 1] = 1 / Z[small]
        return self.K[:2, :2] @ J

    def pixel_to_ray(self, uv) -> np.ndarray:
        uv = _as_uv(uv)
        xy = _affine_rows(uv, self._Kinv)
        rd = np.linalg.norm(xy, axis=1)
        inside = rd <= self._table_td[-1]
        # start from the table of the invertible branch, then Newton within it
        theta = np.interp(rd, self._table_td, self._table_theta)
        f = max(self.K[0, 0], self.K[1, 1])
        done = np.zeros(len(uv), dtype=bool)
        for _ in range(_NEWTON_MAX_IT):
            td, dtd = self._theta_d(theta, deriv=True)
            res = td - rd
            done = np.abs(res) * f < _NEWTON_PX
            if done.all():
                break
            with np.errstate(all="ignore"):
                theta = np.where(done, theta, np.clip(theta - res / dtd, 0.0, self._table_theta[-1]))
        theta[~(done & inside)] = np.nan
        with np.errstate(divide="ignore", invalid="ignore"):
            cphi = np.where(rd > 0, xy[:, 0] / rd, 1.0)
            sphi = np.where(rd > 0, xy[:, 1] / rd, 0.0)
        st = np.sin(theta)
        return np.stack([st * cphi, st * sphi, np.cos(theta)], axis=1)


class OmnidirectionalCamera(CameraModel):
    """Scaramuzza's omnidirectional model [1]_, as C3VD publishes its calibration.

    Pixel to ray: (x, y) = A^-1 (u - cx, v - cy), A = [[c, d], [e, 1]], ray along (x, y, z(|(x, y)|)). Ray to
    pixel: Newton's method on r cos theta - z(r) sin theta, unique while atan2(r, z(r)) grows with r.

    Parameters
    ----------
    cx, cy : float
        Distortion centre, pixels.
    a : array_like of shape (5,)
        a0 .. a4 of z(r) = a0 + a1 r + a2 r^2 + a3 r^3 + a4 r^4 (a0 > 0, pixels).
    c, d, e : float
        The affine stretch A from sensor-plane to pixel offsets.
    image_size : (W, H) or None
        When given, the model must be invertible over the whole frame.

    Raises
    ------
    IntrinsicsError
        Non-finite or boolean parameters, a0 <= 0, a singular stretch, or a polynomial not invertible
        over the frame.
    """

    model = "omnidirectional"

    def __init__(self, cx, cy, a, c, d, e, image_size=None):
        self.cx = finite_number(cx, "cx", IntrinsicsError)
        self.cy = finite_number(cy, "cy", IntrinsicsError)
        a = list(a)
        if len(a) != 5:
            raise IntrinsicsError(f"a: need 5 coefficients a0..a4, got {len(a)}")
        self.a = np.array([finite_number(v, f"a{i}", IntrinsicsError) for i, v in enumerate(a)])
        self.a.setflags(write=False)
        if self.a[0] <= 0:
            raise IntrinsicsError(f"a0: must be > 0 (the focal length on the axis), got {self.a[0]}")
        self.c = finite_number(c, "c", IntrinsicsError)
        self.d = finite_number(d, "d", IntrinsicsError)
        self.e = finite_number(e, "e", IntrinsicsError)
        self.A = np.array([[self.c, self.d], [self.e, 1.0]])
        if abs(np.linalg.det(self.A)) < 1e-9:
            raise IntrinsicsError(f"c, d, e: the stretch [[c, d], [e, 1]] is singular (c - d e = {np.linalg.det(self.A)})")
        self._Ainv = np.linalg.inv(self.A)
        self.image_size = _image_size(image_size, "OmnidirectionalCamera")
        if self.image_size is not None:
            W, H = self.image_size
            corners = np.array([[0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1]], dtype=np.float64)
            rmax = 1.05 * np.linalg.norm((corners - [self.cx, self.cy]) @ self._Ainv.T, axis=1).max()
        else:
            rmax = 4.0 * self.a[0]
        r = np.linspace(0.0, rmax, 8001)
        th = np.arctan2(r, self._z(r))
        if self.image_size is not None:
            if not np.all(np.diff(th) > 0):
                i = int(np.argmax(np.diff(th) <= 0))
                raise IntrinsicsError("a0..a4: not invertible over the frame (the angle off the axis stops "
                                      f"growing at {np.degrees(th[i]):.1f} deg, {r[i]:.4g} px from the centre)")
        else:  # keep the invertible part
            bad = np.diff(th) <= 0
            if bad.any():
                k = int(np.argmax(bad)) + 1
                r, th = r[:k], th[:k]
        self._table_r, self._table_theta = r, th

    def _z(self, r, deriv: bool = False):
        a0, a1, a2, a3, a4 = self.a
        z = a0 + r * (a1 + r * (a2 + r * (a3 + r * a4)))
        return (z, a1 + r * (2 * a2 + r * (3 * a3 + r * 4 * a4))) if deriv else z

    @property
    def principal_point(self) -> np.ndarray:
        return np.array([self.cx, self.cy])

    def params(self) -> dict:
        return {"cx": self.cx, "cy": self.cy, **{f"a{i}": float(v) for i, v in enumerate(self.a)},
                "c": self.c, "d": self.d, "e": self.e}

    def pinhole_stand_in(self) -> PinholeCamera:
        """The pinhole a user without this model would use: f = a0, same centre and size.

        Returns
        -------
        PinholeCamera
            ``K = [[a0, 0, cx], [0, a0, cy], [0, 0, 1]]``.
        """
        K = np.array([[self.a[0], 0.0, self.cx], [0.0, self.a[0], self.cy], [0.0, 0.0, 1.0]])
        return PinholeCamera(K, image_size=self.image_size)

    def pixel_to_ray(self, uv) -> np.ndarray:
        uv = _as_uv(uv)
        xy = _linear_rows(uv - [self.cx, self.cy], self._Ainv)
        r = np.linalg.norm(xy, axis=1)
        p = np.concatenate([xy, self._z(r)[:, None]], axis=1)
        out = p / np.linalg.norm(p, axis=1, keepdims=True)
        out[r > self._table_r[-1]] = np.nan
        return out

    def pixel_to_ray_jacobian(self, uv) -> np.ndarray:
        uv = _as_uv(uv)
        xy = _linear_rows(uv - [self.cx, self.cy], self._Ainv)
        r = np.linalg.norm(xy, axis=1)
        z, dz = self._z(r, deriv=True)
        p = np.concatenate([xy, z[:, None]], axis=1)
        n = np.linalg.norm(p, axis=1)
        dp = np.zeros((len(uv), 3, 2))
        dp[:, :2, :] = self._Ainv
        with np.errstate(divide="ignore", invalid="ignore"):
            drdxy = np.where(r[:, None] > 0, xy / r[:, None], 0.0)  # dr/d(x, y); a1 term vanishes at r = 0 by symmetry
        dp[:, 2, :] = _linear_rows(dz[:, None] * drdxy, self._Ainv.T)
        d = p / n[:, None]
        P = (np.eye(3) - d[:, :, None] * d[:, None, :]) / n[:, None, None]
        out = P @ dp
        out[r > self._table_r[-1]] = np.nan
        return out

    def ray_to_pixel(self, rays) -> np.ndarray:
        rays = _as_rays(rays)
        rho = np.hypot(rays[:, 0], rays[:, 1])
        theta = np.arctan2(rho, rays[:, 2])
        inside = theta <= self._table_theta[-1]
        r = np.interp(theta, self._table_theta, self._table_r)
        ct, st = np.cos(theta), np.sin(theta)
        done = np.zeros(len(rays), dtype=bool)
        for _ in range(_NEWTON_MAX_IT):
            z, dz = self._z(r, deriv=True)
            g = r * ct - z * st
            dg = ct - dz * st
            with np.errstate(all="ignore"):
                step = g / dg
            done = ~(np.abs(step) >= _NEWTON_PX)
            if done.all():
                break
            r = np.where(done, r, np.clip(r - step, 0.0, self._table_r[-1]))
        with np.errstate(divide="ignore", invalid="ignore"):
            cphi = np.where(rho > 0, rays[:, 0] / rho, 1.0)
            sphi = np.where(rho > 0, rays[:, 1] / rho, 0.0)
        xy = r[:, None] * np.stack([cphi, sphi], axis=1)
        out = _linear_rows(xy, self.A) + [self.cx, self.cy]
        out[~(done & inside) | ~np.all(np.isfinite(rays), axis=1)] = np.nan
        return out


def c3vd_camera() -> OmnidirectionalCamera:
    """C3VD's omnidirectional calibration (Olympus CF-HQ190L colonoscope), 1350 x 1080.

    Returns
    -------
    OmnidirectionalCamera
        The published intrinsics (module reference [3], from the dataset's example loader), with the
        centre in this module's convention (pixel centres at integers).

    Examples
    --------
    >>> cam = c3vd_camera()
    >>> cam.image_size
    (1350, 1080)
    >>> bool(abs(cam.ray_to_pixel([[0.0, 0.0, 1.0]])[0] - cam.principal_point).max() < 1e-9)
    True
    """
    return OmnidirectionalCamera(
        cx=678.544839263292, cy=542.975887548343,
        a=(769.243600037458, 0.0, -0.000812770624150226, 6.25674244578925e-07, -1.1966218214428e-09),
        c=0.99998688224999, d=0.00288273829525059, e=-0.00296316513429569, image_size=(1350, 1080))
