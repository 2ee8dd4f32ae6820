"""The start and solve stages of the photometric plane fit: the start planes, each refined by
Levenberg-Marquardt, the best refined again on every pixel and above the floor."""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from simtest.decisions import FLOOR_MARGIN as _FLOOR_MARGIN, RUN_OFF_FACTOR, VALLEY_SCAN_AFTER, VALLEY_SCAN_SPAN
from simtest.geometry.conics import plane_basis
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from simtest.reconstruct.lightaware.model import _mean_light, _normal_derivs, _rays
from simtest.reconstruct.lightaware.plane_model import _NOT_FINITE_RESIDUAL, PlaneModel, start_roughness
from simtest.reconstruct.lightaware.solve import _bisector_plane, _correlated, _implausible, _light_start, _solve


_NAME = "photometric_fit"

#: The most pixels the refinement "on every kept pixel" takes (beyond, a regular sub-grid): 512 x 512,
#: above every ROI of a 360 px frame.
REFINE_MAX_PIXELS = 262_144


def _screened(m: PlaneModel, starts, given):
    """The start (n, h) of least cost before any refinement (at its start roughness)."""
    def cost(nh):
        e1_, e2_ = plane_basis(nh[0])
        return _cost(m, np.array([0.0, 0.0, np.log(nh[1]), np.log(start_roughness(m, *nh, given))]), nh[0], e1_, e2_)
    return min(starts, key=cost)


def start_depths(nominal_depth_mm: float, n: int) -> np.ndarray:
    """The ``n`` start depths (mm) along the BP's ray of a fit's retry: ``nominal_depth_mm`` / 8 to x 8, geometric."""
    return nominal_depth_mm * np.geomspace(1 / 8, 8, n)


def start_planes(m: PlaneModel, rig, d_bp, n0, h0, s) -> list:
    """The start planes (n, h) of a fit: the given start (or, under several lights, the cheapest of the
    mean light's and each light's bisector at the nominal depth, plus ``s.pair_starts``), the nominal
    bisector when a start was given, and ``s.n_start_depths`` bisectors along the BP's constraint
    (nominal/8 to nominal*8); ``s.guide_starts`` alone where given."""
    nominal_depth_mm, rig_arr = s.nominal_depth_mm, m.rig_arr
    if s.guide_starts:
        return [_light_start(d_bp, rig_arr[0][i], d) for i, d in s.guide_starts]
    cands = [(n0, h0)]
    if s.start_normal is None and len(rig_arr[0]) > 1:
        # a highlight is one light's: the cheapest of each light's bisector, and the pairs' starts
        cands = [_screened(m, cands + [_light_start(d_bp, L, nominal_depth_mm) for L in rig_arr[0]], s.start_roughness)]
        cands += [_light_start(d_bp, rig_arr[0][i], d) for i, _, d in s.pair_starts]
    if np.abs(rig_arr[0]).max() > 0:
        Lm = _mean_light(rig)
        depths = list(start_depths(nominal_depth_mm, s.n_start_depths)) if s.n_start_depths else []
        if s.start_normal is not None:
            depths.append(nominal_depth_mm)
        cands += [_bisector_plane(d_bp, Lm, sdep) for sdep in depths]
    return cands


def _finite(m: PlaneModel, r) -> bool:
    """Whether the residuals ``r`` are those of a finite model (below the not-finite residual)."""
    return bool(np.isfinite(r).all() and float(r @ r) < 0.25 * _NOT_FINITE_RESIDUAL**2 * len(m.yn))


def _not_finite(where: str, nfev: int) -> LightAwareEstimate:
    """The ``not_converged`` estimate of a model not finite about the solution (``where``: on which pixels)."""
    return LightAwareEstimate(_NAME, "not_converged", f"the model is not finite about the solution{where}",
                              n_evaluations=nfev)


#: The solves :func:`_again` keeps (least recently used out): the stages ask for one solve again (a
#: retry's starts hold the first try's, a projection's fallback a fit already made).
_SOLVES: OrderedDict = OrderedDict()

#: How many solves :data:`_SOLVES` keeps: each holds a residual vector, 2 MB at the most pixels a fit
#: takes (:data:`REFINE_MAX_PIXELS`), 0.1 MB at a colonoscope highlight's.
_SOLVES_KEPT = 64


def forget_solves() -> None:
    """Empty the solves' memory (:data:`_SOLVES`): a benchmark's repeat of one frame then times the
    solves a user's first run makes, not remembered ones."""
    _SOLVES.clear()


def _again(m: PlaneModel, x, n0, e1, e2, h0, s):
    """``x`` refined on the pixels :meth:`PlaneModel.use` set last: ``(x, nfev, conv, msg, r)``, the same
    solve's result again where its model and inputs are the same (:data:`_SOLVES`)."""
    key = m.digest() + b"".join(np.asarray(a, np.float64).tobytes() for a in (x, n0, e1, e2, h0)) + repr(
        (s.loss, s.f_scale, s.max_nfev, s.diffuse)).encode()
    solved = _SOLVES.get(key)
    if solved is None:
        solved = _SOLVES[key] = _solve_again(m, x, n0, e1, e2, h0, s)
        while len(_SOLVES) > _SOLVES_KEPT:
            _SOLVES.popitem(last=False)
    else:
        _SOLVES.move_to_end(key)
    x_, nfev, conv, msg, r = solved
    return x_.copy(), nfev, conv, msg, r.copy()


class ValleyCoords:
    """Coordinates ``q = (alpha, beta, log d, log roughness)`` of a plane in which the BP's valley is a line.

    The BP fixes the specular point of its light on the BP ray. The planes that keep it there, whose
    normal is the bisector ``b(d)`` of the directions from the ray's point at depth ``d`` to the camera
    and to the light, form a curve along which the cost hardly changes; in the coordinates
    ``p = (a, b, log h, log roughness)`` of :class:`~simtest.reconstruct.lightaware.plane_model.PlaneModel`
    the normal and the distance move together along it. Here the normal is ``unit(b(d) + alpha e1 +
    beta e2)`` and the plane holds the ray's point at depth ``d``: on the curve alpha = beta = 0.

    Parameters
    ----------
    d_bp : ndarray of shape (3,)
        The BP's unit viewing ray, camera frame.
    light_mm : ndarray of shape (3,)
        The BP's light, camera frame, mm; not at the camera centre.
    n0, e1, e2 : ndarray of shape (3,)
        The normal about which ``p`` is written and its plane's basis.
    """

    def __init__(self, d_bp, light_mm, n0, e1, e2):
        self.r, self.L, self.B = d_bp, light_mm, np.array([n0, e1, e2])

    @classmethod
    def of_rig(cls, m: PlaneModel, n0, e1, e2) -> list:
        """The coordinates of each light of the rig of a fit on ``m`` not at the camera centre."""
        d_bp = _rays(m.camera, m.bp[None])[0]
        return [cls(d_bp, L, n0, e1, e2) for L in m.rig_arr[0] if np.abs(L).max() > 0]

    def to_p(self, q):
        """The plane's ``p = (a, b, log h, log roughness)`` at ``q`` (NaN where it turns away from the ray)."""
        d = float(np.exp(q[2]))
        b0, b1, b2 = self.B @ _bisector_plane(self.r, self.L, d)[0]
        p = np.array([(b1 + q[0]) / b0, (b2 + q[1]) / b0, 0.0, q[3]])
        n = _normal_derivs(p, *self.B)[0]
        with np.errstate(invalid="ignore"):
            p[2] = q[2] + np.log(-(n @ self.r))
        return p

    def to_q(self, p):
        """The inverse of :meth:`to_p`; None where the plane faces away from the ray."""
        n = _normal_derivs(p, *self.B)[0]
        nr = -(n @ self.r)
        if not nr > 0:
            return None
        d = float(np.exp(p[2])) / nr
        b0, b1, b2 = self.B @ _bisector_plane(self.r, self.L, d)[0]
        return np.array([p[0] * b0 - b1, p[1] * b0 - b2, np.log(d), p[3]])


def _cost(m: PlaneModel, p, n0, e1, e2) -> float:
    """The sum of squared residuals at ``p`` (about ``n0``); inf where ``p`` or the model is not finite."""
    r = m.resjac_at(p, n0, e1, e2, grad=False)[0] if np.isfinite(p).all() else None
    return float(r @ r) if r is not None and np.isfinite(r).all() else np.inf


def _solve_again(m: PlaneModel, x, n0, e1, e2, h0, s):
    """:func:`_again` without its memory: LM, and where it crawls, LM again from the least cost along
    the BP's valley (:class:`ValleyCoords`, :data:`~simtest.decisions.VALLEY_SCAN_AFTER`)."""
    free = np.ones(len(x), bool)
    free[2] = np.abs(m.rig_arr[0]).max() > 1e-9 * h0  # all lights at V: no dependence on h

    def stop(p) -> str:
        """Why LM's iterate ``p`` is past saving (an overflow is too)."""
        with np.errstate(over="ignore"):
            return _implausible(float(np.exp(p[2])), h0, m.phong_n(p[3]), s.diffuse, widen=RUN_OFF_FACTOR)

    after, (span, n_scan) = VALLEY_SCAN_AFTER, VALLEY_SCAN_SPAN
    lm = dict(lazy_jac=True, weighted=True, newton=True, stop=stop)
    if s.max_nfev <= after + n_scan:
        return _solve(m.resjac_at, x, (n0, e1, e2), s.loss, s.f_scale, s.max_nfev, free, **lm)
    first = x, nfev, conv, msg, r = _solve(m.resjac_at, x, (n0, e1, e2), s.loss, s.f_scale, after, free, **lm)
    if conv or nfev < after or not _finite(m, r):  # (converged, or ran off)
        return first
    # a crawl along the BP's valley: each light's valley scanned about LM's depth, LM resumed from the least cost
    steps = np.linspace(-np.log(span), np.log(span), n_scan)
    scan = [x]
    for c in ValleyCoords.of_rig(m, n0, e1, e2):
        q = c.to_q(x)
        with np.errstate(all="ignore"):
            scan += [] if q is None else [c.to_p(np.array([0.0, 0.0, q[2] + k, q[3]])) for k in steps]
    x, nfev = min(scan, key=lambda p_: _cost(m, p_, n0, e1, e2)), nfev + len(scan) - 1
    x, nfev2, conv, msg, r = _solve(m.resjac_at, x, (n0, e1, e2), s.loss, s.f_scale, s.max_nfev - nfev, free, **lm)
    return x, nfev + nfev2, conv, msg, r


def solve_plane(m: PlaneModel, cands, s, floor_level):
    """Each start refined, the least cost kept and refined once more on every pixel and above the floor.

    Returns ``(x, n0, h0, e1, e2, conv, msg, nfev)`` (``x`` about the normal ``n0`` with basis
    ``e1, e2``, ``h0`` its start distance), or a ``not_converged`` estimate where the model is not
    finite about the solution.
    """
    best, nfev_total = None, 0
    for nc, hc in cands:
        e1, e2 = plane_basis(nc)
        p0 = np.array([0.0, 0.0, np.log(hc), np.log(start_roughness(m, nc, hc, s.start_roughness))])
        x, nfev, conv, msg, r = _again(m, p0, nc, e1, e2, hc, s)
        nfev_total += nfev
        cost = float(r @ r) if np.isfinite(r).all() else np.inf
        if best is None or cost < best[0]:
            best = (cost, x, nc, hc, e1, e2, conv, msg, r)
    if not best[0] < 0.25 * _NOT_FINITE_RESIDUAL**2 * len(m.yn):
        return _not_finite("", nfev_total)
    _, x, n0, h0, e1, e2, conv, msg, r = best
    clipped_low = floor_level is not None and bool(np.any(m.y <= floor_level))
    if m.step > 1 and s.refine_all and not clipped_low and not _correlated(r, m.sel, m.keep.shape, m.step):
        # refined on a sub-grid: where the plane explains it, once more on every kept pixel
        m.use(REFINE_MAX_PIXELS)
        x2, nfev, conv2, msg2, r = _again(m, x, n0, e1, e2, h0, s)
        nfev_total += nfev
        if not _finite(m, r):
            return _not_finite(" on every pixel", nfev_total)
        x, conv, msg = x2, conv2, msg2
    if s.floor_refit and floor_level is not None and m.step == 1 and np.any(m.y <= floor_level):
        # pixels where the model is within a few noise sigmas of the floor (chosen by the model,
        # not their values) are left out and the fit refined on the rest
        r_ = m.resjac_at(x, n0, e1, e2, grad=False)[0]
        model_n = m.yn + r_
        low = m.y <= floor_level
        s_n = 1.4826 * float(np.median(np.abs(r_[~low]))) if np.any(~low) else 0.0
        drop = model_n <= float(floor_level) / m.yscale + _FLOOR_MARGIN * s_n
        if drop.any() and s_n * m.yscale > s.floor_step and np.count_nonzero(~drop & ~m.cens) >= 8 + 1 + int(s.diffuse):
            keep2 = m.keep.copy()
            keep2.flat[m.sel[drop]] = False
            m.use(None, keep2)
            x2, nfev, conv2, msg2, r = _again(m, x, n0, e1, e2, h0, s)
            nfev_total += nfev
            if not _finite(m, r):
                return _not_finite(" above the floor", nfev_total)
            x, conv, msg = x2, conv2, msg2
    return x, n0, h0, e1, e2, conv, msg, nfev_total
