"""The geometry of the curved patches the quadric and cubic fits image: where pixel rays meet a
patch, its normals there, the rig's Phong lobes on it, and each light's specular point on it.

A patch ``p`` is ``(a, b, log s, kappa_xx, kappa_xy, kappa_yy, log n)`` (the quadric of
:func:`~simtest.reconstruct.lightaware.patch.quadric_fit`), with four third-order coefficients
``(gamma_xxx, gamma_xxy, gamma_xyy, gamma_yyy)`` after them for the cubic patch of
:func:`~simtest.reconstruct.lightaware.cubic.cubic_patch_fit`; its apex lies at depth s on the ray
``unit(b_ray + a e1 + b e2)``, its apex normal bisecting the directions to the camera and the
mean light. All in the camera frame (OpenCV axes), mm.
"""

from __future__ import annotations

import functools

import numpy as np

from simtest.geometry.angles import unit
from simtest.geometry.conics import plane_basis
from simtest.reconstruct.lightaware.solve import lm_least_squares

#: Parameters of the quadric patch (a, b, log s, three curvatures, log n) and of the cubic (four third-order more).
QUADRIC_PARAMS = 7
PATCH_PARAMS = QUADRIC_PARAMS + 4


#: Newton steps that take a pixel ray's intersection from the quadric's root to the cubic patch's.
_CUBIC_NEWTON_STEPS = 4

@functools.lru_cache(maxsize=1)
def _ray_basis(b_ray: bytes) -> tuple[np.ndarray, np.ndarray]:
    """``plane_basis`` of the BP ray (its float64 bytes), the last one's kept: a fit images along it thousands of times."""
    return plane_basis(np.frombuffer(b_ray))


def _quadric_root(kxx, kxy, kyy, d, P0, t1, t2, N):
    """Where rays ``t d`` (d (k, 3)) first meet the quadric patch at P0 in the frame (t1, t2, N):
    ``(ax, ay, az, bx, by, bz, t, ok)``, the rays and -P0 in that frame, the ray parameter (inf
    without a root) and where a real, positive, finite root exists. ``k_zz = (k_xx + k_yy) / 2``;
    for K patches: curvatures (K, 1), frame vectors (K, 3), arrays (K, k)."""
    kzz = 0.5 * (kxx + kyy)
    one = P0.ndim == 1  # else stacked: numpy's matmul takes each patch's BLAS gemv as its own (the same bits)
    ax, ay, az = (d @ v if one else np.matmul(d[None], v[:, :, None])[..., 0] for v in (t1, t2, N))
    bx, by, bz = (-(P0 @ v) if one else -np.matmul(P0[:, None, :], v[:, :, None])[..., 0] for v in (t1, t2, N))
    A = 0.5 * (kxx * ax * ax + 2 * kxy * ax * ay + kyy * ay * ay + kzz * az * az)
    B = az + (kxx * ax * bx + kxy * (ax * by + ay * bx) + kyy * ay * by + kzz * az * bz)
    C = bz + 0.5 * (kxx * bx * bx + 2 * kxy * bx * by + kyy * by * by + kzz * bz * bz)
    disc = B * B - 4 * A * C
    ok = disc >= 0
    den = B + np.where(B >= 0, 1.0, -1.0) * np.sqrt(np.where(ok, disc, 0.0))
    good_den = np.abs(den) > 1e-15
    t = np.where(good_den, -2 * C / np.where(good_den, den, 1.0), np.inf)
    ok &= (t > 0) & np.isfinite(t)
    return ax, ay, az, bx, by, bz, t, ok

def _patch_lobes(d, X, ns, ok, s, rough, rig_arr):
    """The rig's Phong lobes (N,) along rays d (N, 3) on a curved patch: points X (N, 3), unit normals
    ns (N, 3), ``ok`` where the ray meets it, apex depth s (the falloff's reference), roughness n; 0
    where the ray misses or the patch faces away. For K patches: X, ns (K, N, 3), s, n (K, 1)."""
    L, w, inv_sq, m = rig_arr
    nv = -np.einsum("...ij,...ij->...i", ns, d)
    out = np.zeros(nv.shape)
    for j in range(len(w)):
        tl = L[j] - X
        r = np.sqrt(np.einsum("...ij,...ij->...i", tl, tl))
        cb = (2.0 * np.einsum("...ij,...ij->...i", ns, tl) * nv + np.einsum("...ij,...ij->...i", tl, d)) / r
        pos = cb > 0
        val = np.where(pos, np.exp(rough * np.log(np.where(pos, cb, 1.0))), 0.0)
        if inv_sq[j]:
            val = val * (s / r) ** 2
        if m[j] > 0:
            val = val * np.maximum((X[..., 2] - L[j, 2]) / r, 0.0) ** m[j]
        out += w[j] * val
    return np.where(ok & (nv > 0), out, 0.0)


def _quadric_frame(b_ray, p, Lm):
    """The apex depth s, apex P0 and frame (N, t1, t2) of the quadric patch ``p`` about the BP ray ``b_ray``, or of K
    patches ``p`` (K, k) as arrays (K,) and (K, 3), each bit for bit its own (norms by ``np.vecdot``: norm's dot)."""
    e1, e2 = _ray_basis(np.asarray(b_ray, np.float64).tobytes())
    def unit_rows(v):
        return v / np.sqrt(np.vecdot(v, v))[:, None]
    P0 = np.exp((q := np.atleast_2d(p))[:, 2:3]) * unit_rows(b_ray + q[:, 0:1] * e1 + q[:, 1:2] * e2)
    N = unit_rows(unit_rows(-P0) + unit_rows(Lm - P0))
    frame = (np.exp(q[:, 2]), P0, N, *plane_basis(N))
    return frame if np.ndim(p) == 2 else tuple(v[0] for v in frame)


def _quadric_image(d, b_ray, p, rig_arr, Lm):
    """Specular image (N,) of the quadric patch ``p = (a, b, log s, kappa_xx, kappa_xy, kappa_yy, log n)``
    along rays d and its apex normal (3,) (:func:`quadric_fit`); for K patches ``p`` (K, 7), images
    (K, N), each bit for bit its own, and normals (K, 3). Rays that miss give 0."""
    s, P0, N, t1, t2 = _quadric_frame(b_ray, p, Lm)
    s = s if np.ndim(p) == 1 else s[:, None]
    kxx, kxy, kyy = p[..., 3:4] / s, p[..., 4:5] / s, p[..., 5:6] / s
    # F = z + (k_xx x^2 + 2 k_xy x y + k_yy y^2) / 2 = 0 along the ray X = t d
    kzz = 0.5 * (kxx + kyy)  # the z^2 term: exact for a sphere
    ax, ay, az, bx, by, bz, t, ok = _quadric_root(kxx, kxy, kyy, d, P0, t1, t2, N)
    t = np.where(ok, t, s)
    x, y, z = ax * t + bx, ay * t + by, az * t + bz
    ns = ((1.0 + kzz * z)[..., None] * N[..., None, :] + (kxx * x + kxy * y)[..., None] * t1[..., None, :]
          + (kxy * x + kyy * y)[..., None] * t2[..., None, :])
    ns /= np.sqrt(np.einsum("...ij,...ij->...i", ns, ns))[..., None]
    return _patch_lobes(d, d * t[..., None], ns, ok, s, np.exp(p[..., 6:7]), rig_arr), N


def _cubic_patch_geometry(d, b_ray, p, Lm):
    """Intersections and surface normals of the cubic patch ``p`` along rays d. Returns
    ``(X (N, 3), ns (N, 3), ok (N,), N (3,), s, frame)``: points and unit normals (camera frame), which rays meet the
    patch in front of the camera, the apex normal, the apex depth s and the apex frame ``(P0, t1, t2, N)``. For K
    patches ``p`` (K, 11): X, ns (K, N, 3), ok (K, N), N (K, 3), s (K, 1), each bit for bit its own."""
    one = np.ndim(p) == 1
    s, P0, N, t1, t2 = _quadric_frame(b_ray, p, Lm)
    s = s if one else s[:, None]
    kxx, kxy, kyy = (p[3] / s, p[4] / s, p[5] / s) if one else (p[:, 3:4] / s, p[:, 4:5] / s, p[:, 5:6] / s)
    kzz = 0.5 * (kxx + kyy)
    c3 = np.asarray(p[..., 7:11], dtype=np.float64) * np.exp(-2.0 * np.asarray(p[..., 2:3], dtype=np.float64))
    cxxx, cxxy, cxyy, cyyy = c3 if one else c3.T[:, :, None]
    # the quadric's root (as in _quadric_image), then Newton on the full F along the ray
    ax, ay, az, bx, by, bz, t, ok = _quadric_root(kxx, kxy, kyy, d, P0, t1, t2, N)
    t = np.where(ok, t, s)

    def grad(t):
        x, y, z = ax * t + bx, ay * t + by, az * t + bz
        fx = kxx * x + kxy * y + 0.5 * (cxxx * x * x + 2 * cxxy * x * y + cxyy * y * y)
        fy = kxy * x + kyy * y + 0.5 * (cxxy * x * x + 2 * cxyy * x * y + cyyy * y * y)
        return x, y, z, fx, fy, 1.0 + kzz * z

    cubic = np.any(c3 != 0, axis=-1, keepdims=not one)  # a quadric patch keeps the quadric's root
    for _ in range(_CUBIC_NEWTON_STEPS if np.any(cubic) else 0):
        x, y, z, fx, fy, fz = grad(t)
        # (x * x * x, not x**3: pow of a negative base costs a hundred times a product)
        F = (z + 0.5 * (kxx * x * x + 2 * kxy * x * y + kyy * y * y + kzz * z * z)
             + (cxxx * x * x * x + 3 * cxxy * x * x * y + 3 * cxyy * x * y * y + cyyy * y * y * y) / 6.0)
        dF = fx * ax + fy * ay + fz * az
        good = np.abs(dF) > 1e-12
        t = np.where(cubic, t - np.where(good, F / np.where(good, dF, 1.0), 0.0), t)
    ok &= (t > 0) & np.isfinite(t)
    t = np.where(ok, t, s)
    _, _, _, fx, fy, fz = grad(t)
    ns = fz[..., None] * N[..., None, :] + fx[..., None] * t1[..., None, :] + fy[..., None] * t2[..., None, :]
    ns /= np.sqrt(np.einsum("...ij,...ij->...i", ns, ns))[..., None]
    return d * t[..., None], ns, ok, N, s, (P0, t1, t2, N)


def _cubic_patch_image(d, b_ray, p, rig_arr, Lm):
    """Specular image (N,) of the cubic patch ``p`` along rays d, and its apex normal (3,); for K patches
    ``p`` (K, 11), images (K, N) and normals (K, 3), each bit for bit its own."""
    X, ns, ok, N, s, _ = _cubic_patch_geometry(d, b_ray, p, Lm)
    return _patch_lobes(d, X, ns, ok, s, np.exp(p[..., 6:7] if np.ndim(p) == 2 else p[6]), rig_arr), N


def _patch_specular_points(b_ray, p, Lm, lights):
    """Each light's specular point on the patch ``p`` (7 parameters: a quadric, 11: a cubic patch): unit
    normals (J, 3) and depths (J,). Searched along the rays ``unit(b + u e1 + v e2)`` by Levenberg-Marquardt
    from the apex's ray, where the normal bisects the directions to the camera and the light; NaN rows where
    it fails."""
    p = np.concatenate([p, np.zeros(PATCH_PARAMS - len(p))])  # a quadric: the third-order terms 0
    e1, e2 = plane_basis(b_ray)
    ray0 = np.array([p[0], p[1]], dtype=np.float64)
    normals = np.full((len(lights), 3), np.nan)
    depths = np.full(len(lights), np.nan)
    for j, Lj in enumerate(lights):
        def f(q, Lj=Lj):
            X, ns, ok, _, _, _ = _cubic_patch_geometry(unit(b_ray + q[0] * e1 + q[1] * e2)[None], b_ray, p, Lm)
            if not ok[0]:
                return np.array([1.0, 1.0])
            c = ns[0] - unit(unit(-X[0]) + unit(Lj - X[0]))
            return np.array([c @ e1, c @ e2])

        with np.errstate(all="ignore"):
            r = lm_least_squares(f, ray0, xtol=1e-14, ftol=1e-14, gtol=1e-14)
        X, ns, ok, _, _, _ = _cubic_patch_geometry(unit(b_ray + r.x[0] * e1 + r.x[1] * e2)[None], b_ray, p, Lm)
        if ok[0] and float(np.max(np.abs(r.fun))) < 1e-9:
            normals[j], depths[j] = ns[0], float(np.linalg.norm(X[0]))
    return normals, depths


def _light_normal_jacobian(b_ray, p, Lm, lights, x_scale) -> np.ndarray:
    """The derivative (J, 3, k) of each light's specular-point normal in the patch's k parameters (7 or 11), by
    central differences (1e-4 of ``x_scale``, (k,); NaN where a specular point is not found)."""
    h = 1e-4 * np.asarray(x_scale, dtype=np.float64)
    return np.stack([(_patch_specular_points(b_ray, p + e, Lm, lights)[0]
                      - _patch_specular_points(b_ray, p - e, Lm, lights)[0]) / (2 * hi) for e, hi in zip(np.diag(h), h)],
                    axis=-1)
