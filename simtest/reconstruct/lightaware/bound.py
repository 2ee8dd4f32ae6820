"""The Cramer-Rao bound of the photometric plane model under per-pixel Gaussian noise."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.geometry.angles import unit
from simtest.geometry.conics import plane_basis
from simtest.geometry.lights import LightRig
from simtest.reconstruct.lightaware.model import (
    _camera, _log_depth_gradient, _mean_light, _normal_derivs, _rays, _rig_arrays, _rig_image,
)
from simtest.reconstruct.lightaware.solve import _covariance


@dataclass(frozen=True)
class CramerRaoBound:
    """Lower bounds on the standard deviations of an unbiased photometric estimate.

    Attributes
    ----------
    normal_deg : float
        RMS angle of the normal's error, degrees (``sqrt(C_aa + C_bb)``).
    depth_rel : float
        Relative standard deviation of the specular point's depth (inf when not observable).
    n_pixels : int
        Pixels that carry the information (unclipped pixels of the ROI).
    """

    normal_deg: float
    depth_rel: float
    n_pixels: int


def photometric_crb(camera, origin_uv, shape, normal, distance_mm: float, rig: LightRig, roughness: float, gain: float,
                    sigma: float, *, background=(0.0, 0.0, 0.0), bp_uv=None,
                    clip_level: float | None = None) -> CramerRaoBound:
    """Cramer-Rao bound of the photometric model under per-pixel Gaussian noise.

    ``C = (J^T J / sigma^2)^-1``, J the Jacobian of the noise-free image of :func:`photometric_fit`'s
    model in (a, b, log h, log n, g, b0, b1, b2) over the unclipped pixels (nuisance parameters
    included). Normal ``sqrt(C_aa + C_bb)``; depth by the delta method through the mean light.

    Parameters
    ----------
    camera, origin_uv, rig
        As in :func:`photometric_fit`.
    shape : (H, W)
        ROI size, px.
    normal, distance_mm, roughness
        The true unit normal (3,) facing the camera, plane distance h (mm) and Phong n.
    gain, sigma : float
        Image units per unit of the model, and the noise's standard deviation in image units.
    background : (b0, b1, b2)
        Linear background ``b0 + b1 du + b2 dv`` (du, dv the offsets from ``bp_uv`` over the ROI's
        larger side), image units.
    bp_uv : array_like of shape (2,), optional
        The reference pixel of the background (default the ROI centre).
    clip_level : float, optional
        Pixels whose noise-free value reaches it are left out.

    Returns
    -------
    CramerRaoBound

    Raises
    ------
    ValueError
        If sigma is not > 0.
    """
    if not sigma > 0:
        raise ValueError(f"sigma: must be > 0, got {sigma}")
    camera = _camera(camera)
    H, W = (int(v) for v in shape)
    o = np.asarray(origin_uv, dtype=np.float64).reshape(2)
    vv, uu = np.mgrid[0:H, 0:W]
    uv = np.column_stack([uu.ravel() + o[0], vv.ravel() + o[1]]).astype(np.float64)
    ref = o + [(W - 1) / 2, (H - 1) / 2] if bp_uv is None else np.asarray(bp_uv, dtype=np.float64)
    du, dv = ((uv - ref) / max(W, H)).T
    d = _rays(camera, uv)
    n = unit(np.asarray(normal, dtype=np.float64))
    e1, e2 = plane_basis(n)
    _, dns = _normal_derivs(np.zeros(2), n, e1, e2)
    S, dS = _rig_image(d, n, dns, float(distance_mm), _rig_arrays(rig), float(roughness))
    b0, b1, b2 = (float(v) for v in background)
    img = gain * S + b0 + b1 * du + b2 * dv
    keep = np.ones(len(img), bool) if clip_level is None else img < clip_level
    J = np.column_stack([gain * dS, S, np.ones_like(S), du, dv])[keep]
    cov = _covariance(J, sigma**2)
    if cov is None:  # h not observable: bound the normal with h held (its column removed)
        covr = _covariance(np.delete(J, 2, axis=1), sigma**2)
        nd = float("inf") if covr is None else float(np.degrees(np.sqrt(covr[0, 0] + covr[1, 1])))
        return CramerRaoBound(nd, float("inf"), int(keep.sum()))
    g = _log_depth_gradient(n, float(distance_mm), _mean_light(rig))
    return CramerRaoBound(float(np.degrees(np.sqrt(cov[0, 0] + cov[1, 1]))),
                          float(np.sqrt(max(g @ cov[:3, :3] @ g, 0.0))), int(keep.sum()))
