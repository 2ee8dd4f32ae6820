"""Under one light the quadric fit's depth trades with the surface's third-order shape (issue 10,
issue 39): the fit gives no depth, its normal's sigma spans the depths the data cannot exclude,
and the BP ray's expected error is not read at a depth the fit cannot vouch for.

Exact synthetic images: a third-order patch (:func:`_cubic_patch_image`, the cubic patch fit's
own model) lit by one light 4 mm beside the lens, its apex 40 mm away (epsilon/d 0.1), 60 x 60 px,
8-bit with read noise 0.5 counts (so that the quadric's misfit test passes, as on the renders).
"""
from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np

from simtest.geometry import angle_between_deg
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct import lightaware as la
from simtest.reconstruct.lightaware.model import _mean_light, _rays, _rig_arrays
from simtest.reconstruct.lightaware.cubic import _cubic_patch_image
from simtest.reconstruct.lightaware.patch import ONE_LIGHT_DEPTH_FACTOR
from simtest.reconstruct.io import _light_aware_dict
from simtest.reconstruct.recommend import bp_error_depth_mm, bp_ray_error_deg, recommend

K = np.array([[150.0, 0, 29.5], [0, 150.0, 29.5], [0, 0, 1.0]])
DEPTH = 40.0
BP = np.array([29.5, 29.5])


def _cubic_one_light(c, kappa=(3.0, 0.0, 0.8), seed=0):
    """8-bit image of the third-order patch with dimensionless cubic terms ``c`` (4,) and its
    apex normal (the light's specular point's: the apex is where the normal bisects)."""
    rig = LightRig((Light((4.0, 0.0, 0.0), 1.0, "none"),))
    b_ray = _rays(K, BP[None])[0]
    uu, vv = np.meshgrid(np.arange(60.0), np.arange(60.0))
    d = _rays(K, np.column_stack([uu.ravel(), vv.ravel()]))
    p = np.array([0.0, 0.0, np.log(DEPTH), *kappa, np.log(60.0), *c])
    img, N = _cubic_patch_image(d, b_ray, p, _rig_arrays(rig), _mean_light(rig))
    img = img.reshape(60, 60) / img.max() * 200.0
    rng = np.random.default_rng(seed)
    return np.clip(np.round(img + 0.5 * rng.normal(size=img.shape)), 0, 255), rig, N


def test_one_light_quadric_gives_no_depth_and_its_band_holds_the_truth():
    # c_xxx = 1 (a curvature that grows along the light's offset): the quadric's misfit test
    # passes and its depth is 57.5 mm where the truth is 40 (+44 %, measured); before, that
    # depth was released with the status ok (its normal 0.87 deg off, sigma 1.2). Now: no
    # depth, the band (23 to 144 mm) holds the truth, and the error is within twice the widened
    # sigma (1.9)
    img, rig, N = _cubic_one_light((1.0, 0.0, 0.0, 0.0))
    est = la.quadric_fit(img, (0, 0), BP, K, rig, nominal_depth_mm=20.0)
    assert est.status == "depth_not_observable", est
    assert est.depth_mm is None and est.depth_sigma_mm is None and est.distance_mm is None
    near, far = est.depth_range_mm
    assert near < DEPTH < far
    assert np.isclose(far / near, ONE_LIGHT_DEPTH_FACTOR**2)
    assert angle_between_deg(est.normal, N) <= 2.0 * est.normal_sigma_deg


def test_one_light_quadric_is_not_recommended_over_the_bp_ray():
    # on the 30 px ROI (the recommendation's 1.5 times a 20 px highlight) the quadric was ok
    # with its depth 52.5 mm (+31 %) and recommended by rule 1; its normal was 0.67 deg off,
    # better than the BP ray's 2.86 here, but the data cannot tell this patch from one where
    # the same fit errs more (the liver render: 3.84 against 2.89). Now its depth is withdrawn
    # and the BP ray's expected error is read at the band's far end (131 mm: 0.87 deg), its
    # least, not at the fit's depth (2.2 deg) or the nominal 20 mm (5.7 deg), beside a sigma
    # of 1.9: the BP ray
    img, rig, N = _cubic_one_light((1.0, 0.0, 0.0, 0.0))
    ray = _rays(K, BP[None])[0]
    q = la.quadric_fit(img[15:45, 15:45], (15, 15), BP, K, rig, nominal_depth_mm=20.0)
    assert q.status == "depth_not_observable" and q.depth_range_mm is not None
    assert bp_error_depth_mm(q, 20.0) == q.depth_range_mm[1]
    q = dataclasses.replace(q, bp_ray_error_deg=bp_ray_error_deg(ray, bp_error_depth_mm(q, 20.0), rig))
    assert q.bp_ray_error_deg < bp_ray_error_deg(ray, DEPTH, rig)  # a lower bound
    rec = recommend(SimpleNamespace(light_aware={"quadric_fit": q}, bp_ray=-ray))
    assert rec.normal_from == "bp_ray"
    # and a fit with a depth is read at it, one without either at the nominal depth
    assert bp_error_depth_mm(dataclasses.replace(q, depth_mm=33.0), 20.0) == 33.0
    assert bp_error_depth_mm(dataclasses.replace(q, depth_range_mm=None), 20.0) == 20.0
    # estimates.json states the band in place of the depth
    entry = _light_aware_dict({"quadric_fit": q})["quadric_fit"]
    assert entry["depth_mm"] is None and entry["depth_range_mm"] == list(q.depth_range_mm)


def test_two_light_quadric_keeps_its_depth():
    # the band is for one light only: with guides either side of the lens the quadric's fit is
    # as before (its depth released where it passes the ceiling), so the rig's figures stand
    rig2 = LightRig((Light((-4.0, 0.0, 0.0), 1.0, "none"), Light((4.0, 0.0, 0.0), 1.0, "none")))
    b_ray = _rays(K, BP[None])[0]
    uu, vv = np.meshgrid(np.arange(60.0), np.arange(60.0))
    d = _rays(K, np.column_stack([uu.ravel(), vv.ravel()]))
    p = np.array([0.0, 0.0, np.log(DEPTH), 3.0, 0.0, 0.8, np.log(60.0), 0, 0, 0, 0])
    img = _cubic_patch_image(d, b_ray, p, _rig_arrays(rig2), _mean_light(rig2))[0]
    img = np.round(img.reshape(60, 60) / img.max() * 200.0)
    est = la.quadric_fit(img, (0, 0), BP, K, rig2, nominal_depth_mm=20.0)
    assert est.depth_range_mm is None
    assert "one light" not in est.detail
