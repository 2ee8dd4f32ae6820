"""The covariance stage of the photometric plane fit: the misfit tests at the solution and the
sigmas that count the residual's correlation."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from simtest.geometry.conics import plane_basis
from simtest.tolerances import TOL
from simtest.reconstruct.lightaware.estimate import LightAwareEstimate
from simtest.reconstruct.lightaware.model import _curvature_columns, _mean_light, _normal_derivs
from simtest.reconstruct.lightaware.plane_model import PlaneModel
from simtest.reconstruct.lightaware.plane_solve import _FLOOR_MARGIN
from simtest.reconstruct.lightaware.solve import (
    _cluster_covariance, _cluster_terms, _correlated, _correlation_area, _curvature_score, _curvature_shift,
    _hac_covariance, _misfit, cluster_blocks,
)


def _with_depth_sigma(est: LightAwareEstimate, dsig: float, why) -> LightAwareEstimate:
    """``est`` with the depth's 1-sigma ``dsig`` (mm), or ``depth_not_observable`` (detail ``why(rel)``)
    where ``dsig`` exceeds ``TOL.depth_rel_sigma_max`` of a nonzero depth."""
    if est.depth_mm and dsig > TOL.depth_rel_sigma_max * abs(est.depth_mm):
        return est.without_depth("depth_not_observable", why(dsig / abs(est.depth_mm)))
    return replace(est, depth_sigma_mm=dsig)


class PlaneVerdict:
    """The verdict on a solved plane fit for :func:`~simtest.reconstruct.lightaware.solve._finish`:
    :meth:`at_solution` (residuals and Jacobian) and :meth:`post` (misfit tests and sigmas)."""

    def __init__(self, m: PlaneModel, rig, x, n0, e1, e2, n_hat, h_hat, rough_hat, how, floor_level):
        self.m, self.rig, self.x, self.n0, self.e1, self.e2 = m, rig, x, n0, e1, e2
        self.n_hat, self.h_hat, self.rough_hat = n_hat, h_hat, rough_hat
        self.how, self.floor_level = how, floor_level
        self._last = None  # (key, (r, J)) of the last at_solution

    def at_solution(self, p_hat, nb, e1_, e2_):
        """Residuals and covariance Jacobian at the solution x, derivatives about (nb, e1_, e2_) (read-only;
        the estimate's covariance and the misfit tests ask for the same point: computed once)."""
        key = b"".join(np.asarray(a, np.float64).tobytes() for a in (p_hat, nb, e1_, e2_))
        if self._last is None or self._last[0] != key:
            m = self.m
            m.resjac_at(self.x, self.n0, self.e1, self.e2, grad=False)
            dn = _normal_derivs(p_hat, nb, e1_, e2_)[1]  # general: the diffuse column's by differences about nb
            J = m.jac_general(p_hat, nb, e1_, e2_, dn, None) if m.general else m.jac_of(dn, None, True)
            r = m.state["r"].copy()
            r.flags.writeable = J.flags.writeable = False
            self._last = (key, (r, J))
        return self._last[1]

    def _jacobian(self):
        """The covariance Jacobian at the solution, about its own normal."""
        return self.at_solution(np.concatenate([[0.0, 0.0, np.log(self.h_hat)], self.x[3:]]), self.n_hat,
                                *plane_basis(self.n_hat))[1]

    def curvature(self, r0, hac=False):
        """The score test for a curved patch about the mean light's specular point:
        ``(verdict, shift)``, the test's detail (None: passes, False: cannot be made) and, for a misfit,
        :func:`~simtest.reconstruct.lightaware.solve._curvature_shift`."""
        m, n_hat, h_hat, floor_level = self.m, self.n_hat, self.h_hat, self.floor_level
        Lm = _mean_light(self.rig)
        c = float(n_hat @ Lm) + h_hat
        Lp = Lm - 2.0 * c * n_hat  # the mean light's mirror image in the plane
        den = -float(n_hat @ Lp)
        if not (c > 0 and den > 0):
            return False, None
        Xs = Lp * (h_hat / den)
        cols = m.box(_curvature_columns(m.dT, m.rl, n_hat, h_hat, m.rig_arr, self.rough_hat, Xs)).T
        J = self._jacobian()
        span = np.column_stack([J, m.design] if m.general else [J, m.state["St"], m.background])
        sel_ = m.sel
        if floor_level is not None and np.any(m.y <= floor_level):
            # the pixels near the floor hold clipped noise: the test reads the rest (chosen by the model)
            above = m.y > floor_level
            s_n = 1.4826 * float(np.median(np.abs(r0[above]))) if np.any(above) else 0.0
            rows = m.yn + r0 > float(floor_level) / m.yscale + _FLOOR_MARGIN * s_n
            cols, span, r0, sel_ = cols[rows], span[rows], r0[rows], m.sel[rows]
        verdict = _curvature_score(cols, span, r0, (sel_, m.keep.shape, m.step) if hac else None)
        return verdict, (_curvature_shift(cols, span, r0) if verdict else None)

    def post(self, est, r0):
        """The misfit tests and sigmas: the neighbours' correlation and the curvature test on the plain
        path (sandwich sigmas where the residuals correlate), :meth:`sensor_verdict` on the sensor path."""
        m = self.m
        if est.status not in ("ok", "depth_not_observable"):
            return est
        if m.general:
            return self.sensor_verdict(est, r0)
        if not _correlated(r0, m.sel, m.keep.shape, m.step):
            curved, shift = self.curvature(r0)
            if curved:
                return self.immaterial(est, r0, curved, shift, False, False)
            return self.counted(est, r0, False, jackknife=False)
        return _misfit(self.with_sandwich(est, r0), r0, m.sel, m.keep.shape, m.step)

    def with_sandwich(self, est, r0):
        """``est`` with the normal's sigma at least the sandwich's."""
        m = self.m
        cov, _ = _hac_covariance(self._jacobian(), r0, m.sel, m.keep.shape, m.step)
        if cov is not None:
            sig = math.degrees(math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0)))
            est = replace(est, normal_sigma_deg=max(sig, est.normal_sigma_deg or 0.0))
        return est

    def sensor_verdict(self, est, r0):
        """The misfit test and sigmas of the sensor path: the curvature's score test against the residual's
        own correlated noise (an albedo texture passes, a curved patch does not), sigmas by
        :meth:`counted`; where the test cannot be made, the neighbours' correlation decides."""
        m = self.m
        curved, shift = self.curvature(r0, hac=True)
        correlated = _correlated(r0, m.sel, m.keep.shape, m.step)
        if curved:
            return self.immaterial(est, r0, curved, shift, correlated, True)
        if curved is False:
            return _misfit(self.with_sandwich(est, r0), r0, m.sel, m.keep.shape, m.step) if correlated else est
        return self.counted(est, r0, correlated)

    def immaterial(self, est, r0, curved, shift, correlated, jackknife):
        """A fit whose residual holds a curved pattern (``curved``) that moves the normal by at most its
        sigma (:meth:`counted`, wide blocks), kept with its sigmas grown by the shift; else ``est`` as a
        ``plane_misfit``."""
        if shift is None:
            return est.without_depth("plane_misfit", curved)
        kept = self.counted(est, r0, correlated, jackknife=jackknife, wide=True)
        sig = kept.normal_sigma_deg
        if kept.status not in ("ok", "depth_not_observable") or sig is None or not shift[0] <= sig:
            return est.without_depth("plane_misfit", curved)
        note = (f"{curved}, which moves the normal {shift[0]:.2g} deg, within its sigma: "
                "kept, its sigmas grown by the shift")
        kept = replace(kept, normal_sigma_deg=sig + shift[0], curvature_shift_deg=shift[0]).noted(note)
        if kept.depth_sigma_mm is not None and kept.depth_mm:
            return _with_depth_sigma(kept, kept.depth_sigma_mm + shift[1] * abs(kept.depth_mm),
                                     lambda rel: f"{kept.detail}; relative depth sigma {rel:.3g} > "
                                                 f"{TOL.depth_rel_sigma_max}")
        return kept

    def counted(self, est, r0, correlated, jackknife=True, wide=False):
        """``est`` with sigmas that count the residual's correlation: ``s^2 (J^T J)^-1`` times its correlation
        area, the normal's at least the sandwich's where the residuals correlate and, with ``jackknife``,
        the cluster jackknife's; the depth's grown by the same factor, withdrawn above
        ``TOL.depth_rel_sigma_max``."""
        m = self.m
        scale = math.sqrt(_correlation_area(r0, m.sel, m.keep.shape, m.step))
        sig = None if est.normal_sigma_deg is None else est.normal_sigma_deg * scale
        est = replace(est, normal_sigma_deg=sig)
        if correlated:
            est = self.with_sandwich(est, r0)
        if est.normal_sigma_deg and jackknife:
            # at least the cluster jackknife's over the blocks; the depth's sigma grows by the same factor
            J = self._jacobian()
            terms = _cluster_terms(J, r0, m.sel, m.keep.shape[1])  # (read by every block side)
            for block in cluster_blocks(m.keep.shape, texture=wide or self.how in (None, "darkest_channel")):
                cov = _cluster_covariance(J, r0, m.sel, m.keep.shape, block, terms)  # None: no test
                csig = -1.0 if cov is None else math.degrees(math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0)))
                if csig > est.normal_sigma_deg:
                    scale *= csig / est.normal_sigma_deg
                    est = replace(est, normal_sigma_deg=csig)
        if est.depth_sigma_mm is not None:
            return _with_depth_sigma(est, est.depth_sigma_mm * scale,
                                     lambda rel: f"relative depth sigma {rel:.3g} with the residual's "
                                                 f"correlation > {TOL.depth_rel_sigma_max}")
        return est
