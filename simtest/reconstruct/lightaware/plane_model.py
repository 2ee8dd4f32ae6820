"""The lobe stage of the photometric plane fit: the ROI's pixels, the rig's image of a plane at
(a, b, log h, log roughness), the variable projection's residual and Jacobian, the start roughness."""

from __future__ import annotations

import hashlib
import pickle

import numpy as np

from simtest._lazy import require
from simtest.reconstruct._pixels import border_ring
from simtest.reconstruct.lightaware.model import (
    BLINN_PER_PHONG, _normal_derivs, _ray_light, _rays, _rig_arrays, _rig_diffuse, _rig_diffuse_grad, _rig_geometry,
    _rig_grad, _rig_grad_ggx, _rig_value, _rig_value_ggx, _roi_grid, _roi_samples, ggx_alpha_of_phong, phong_of_ggx_alpha,
)
from simtest.reconstruct.lightaware.solve import _ROUGHNESS_RANGE


#: The residual of every pixel where the model is not finite: far above any normalised residual, so LM rejects it.
_NOT_FINITE_RESIDUAL = 1e6

#: The lights the pixel caps (``FitSettings.max_pixels``, ``REFINE_MAX_PIXELS``) are set for, the colonoscope's two
#: guides: a rig of L lights fits ``CAP_LIGHTS / L`` of them, each model evaluation costing pixels times lights.
CAP_LIGHTS = 2

#: Background bases :meth:`PlaneModel._background_basis` keeps (oldest out): the active sets one solve visits.
_BASES_KEPT = 4

#: Gauss-Newton steps on log n alone that refine the photometric fit's start roughness.
_ROUGHNESS_START_STEPS = 3

#: Phong roughnesses (a factor of 4 apart) among which a start under several lights is chosen by its cost.
_START_ROUGHNESS_GRID = (4.0, 16.0, 64.0, 256.0, 1024.0, 4096.0)

#: The factor by which the grid's start roughness must lower the start plane's cost to replace the regression's.
_START_ROUGHNESS_GAIN = 0.5


def _qr_rows(AT, scratch: bool):
    """``(QT (k, M), R)``: the reduced QR of ``AT.T`` by LAPACK in place (``scratch``: ``AT`` may be overwritten)."""
    lapack = require("scipy.linalg").lapack
    qr, tau = lapack.dgeqrf(AT.T, overwrite_a=scratch)[:2]
    R = np.triu(qr[:len(AT)])
    return lapack.dorgqr(qr, tau, overwrite_a=True)[0].T, R


class PlaneModel:
    """The pixels of one photometric plane fit and the model's residuals on them.

    :meth:`use` picks the pixels fitted and sets the arrays the residuals read. ``general`` (a
    diffuse column, censored rows or the GGX lobe) selects :meth:`resjac_general`, else
    :meth:`resjac_plain`. The last evaluation is cached in ``state``, the background's basis in ``proj``.

    Raises
    ------
    ValueError
        A values array that is not 2-D and finite, an ``exclude`` mask of another shape, or a
        supersampling below 1.
    """

    def __init__(self, values, origin_uv, bp_uv, camera, rig, s, clip_level, lower, missing, ggx):
        self.censor = censor = bool(s.censor and (clip_level is not None or lower is not None))
        vals, self.camera, self.o, self.uu, self.vv, keep = _roi_grid(values, camera, origin_uv,
                                                                      None if censor else clip_level)
        if lower is not None:
            keep &= ~missing if censor else ~(missing | lower)
        if s.exclude is not None:
            ex = np.asarray(s.exclude, dtype=bool)
            if ex.shape != keep.shape:
                raise ValueError(f"exclude: shape {ex.shape} is not the ROI's {keep.shape}")
            keep &= ~ex
        self.vals, self.keep, self.lower, self.clip_level = vals, keep, lower, clip_level
        self.diffuse, self.ggx, self.blinn = s.diffuse, ggx, s.lobe == "blinn"
        self.H, self.W = vals.shape
        self.b_level = float(np.median(border_ring(vals)))
        self.ss = ss = int(s.supersample)
        if ss < 1:
            raise ValueError(f"supersample: must be >= 1, got {s.supersample!r}")
        offs = (np.arange(ss) + 0.5) / ss - 0.5
        self.sub = np.array([(du_, dv_) for dv_ in offs for du_ in offs])  # (ss^2, 2)
        self.rig_arr = _rig_arrays(rig)
        self.bp = np.asarray(bp_uv, dtype=np.float64).reshape(2)
        self.use(s.max_pixels)

    def use(self, mp, keep_=None):
        """Fit the pixels of ``keep_`` (default every kept one), on a sub-grid beyond ``mp``; caches dropped."""
        keep_ = self.keep if keep_ is None else keep_
        if mp and len(self.rig_arr[1]) > CAP_LIGHTS:  # the caps bound pixels x lights
            mp = max(mp * CAP_LIGHTS // len(self.rig_arr[1]), 1)
        lower, censor, clip_level = self.lower, self.censor, self.clip_level
        sel_, self.step, uv_, y_ = _roi_samples(self.vals, self.o, self.uu, self.vv, keep_, mp)
        self.sel, self.y = sel_, y_
        self.cens = ((lower.ravel()[sel_] if lower is not None else y_ >= clip_level) if censor
                     else np.zeros(len(y_), bool))
        self.dT = dT_ = np.ascontiguousarray(_rays(self.camera, (uv_[:, None, :] + self.sub[None]).reshape(-1, 2)).T)
        du_, dv_ = ((uv_ - self.bp) / max(self.W, self.H)).T
        self.yscale = yscale_ = max(float(np.abs(y_).max()), 1e-12)
        self.background = np.column_stack([np.ones_like(du_), du_, dv_])
        self.design = np.empty((5 if self.diffuse else 4, len(y_))).T  # (each column contiguous: _qr_rows)
        self.design[:, -3:] = self.background
        self.general = bool(self.diffuse or self.cens.any() or self.ggx)
        self.rl, self.yn = _ray_light(self.rig_arr[0], dT_), y_ / yscale_
        self.clipn = ((y_ / yscale_ if lower is not None else float(clip_level) / yscale_) if censor else np.inf)
        # caches: the last evaluation; the background's basis per weights (proj), per active set (lin); start roughness
        self.state, self.proj, self.lin, self.starts = {}, {}, {}, {}
        self._digest = None  # (:meth:`digest`, computed when first asked for)

    def digest(self) -> bytes:
        """A digest of everything the residuals read on the pixels :meth:`use` set: equal digests, equal
        residuals at every point. Left out: the caches, and the arrays :meth:`use` derives from those
        hashed (the samples' rays, background columns, values; ``y`` is ``vals`` at ``sel``)."""
        if self._digest is None:
            skip = {"state", "proj", "lin", "starts", "design", "_digest", "dT", "rl", "background", "y", "yn",
                    "clipn"}
            arrays: list = []  # (the arrays' buffers hashed in place, not copied into the pickle)
            h = hashlib.sha1(pickle.dumps({k: v for k, v in self.__dict__.items() if k not in skip}, protocol=5,
                                          buffer_callback=arrays.append), usedforsecurity=False)
            for a in arrays:
                h.update(a.raw())
            self._digest = h.digest()
        return self._digest

    def basis(self, w):
        """``QT`` (3, M), the background's orthonormal basis (rows), and the projected values."""
        proj = self.proj
        key = None if w is None else w.tobytes()
        if proj.get("key") != key or "QT" not in proj:
            B = self.background if w is None else self.background * w[:, None]
            QT = np.ascontiguousarray(np.linalg.qr(B)[0].T)
            yw = self.yn if w is None else self.yn * w
            proj.update(key=key, QT=QT, yt=yw - (QT @ yw) @ QT)
        return proj["QT"], proj["yt"]

    def phong_n(self, log_rough: float) -> float:
        """The Phong n of the lobe's roughness parameter ``exp(log_rough)`` (GGX's alpha, Blinn's exponent)."""
        with np.errstate(over="ignore"):  # a fit run off to an infinite roughness
            rough = float(np.exp(log_rough))
        return phong_of_ggx_alpha(rough) if self.ggx else rough / BLINN_PER_PHONG if self.blinn else rough

    def box(self, v):
        """The mean of each pixel's sub-pixel samples (the last axis)."""
        return v if self.ss == 1 else v.reshape(*v.shape[:-1], -1, self.ss * self.ss).mean(axis=-1)

    def resjac_at(self, p, nb, e1, e2, grad=True, w=None):
        """Residuals (M,) and Jacobian (M, 4) at ``p`` = (a, b, log h, log roughness) about ``nb``."""
        return (self.resjac_general if self.general else self.resjac_plain)(p, nb, e1, e2, grad, w)

    def resjac_general(self, p, nb, e1, e2, grad=True, w=None):
        """Residuals and Kaufman's Jacobian with the diffuse column and censored rows; a row where the model
        is at or above the clip level reads it (residual 0 if censored, else the clip less its value)."""
        state, design, yn, cens = self.state, self.design, self.yn, self.cens
        dT, rl, rig_arr, box = self.dT, self.rl, self.rig_arr, self.box
        key = (p.tobytes(), nb.tobytes(), None if w is None else w.tobytes(), "general")
        if state.get("key") != key:
            n, dns = _normal_derivs(p, nb, e1, e2)
            h, rough = float(np.exp(p[2])), float(np.exp(p[3]))
            S, parts = (_rig_value_ggx(dT, rl, n, h, rig_arr, rough, parts=(parts := [])), parts) if self.ggx \
                else _rig_value(dT, rl, n, h, rig_arr, rough, blinn=self.blinn)
            design[:, 0], terms = box(S), None
            if self.diffuse:  # (cb, delta, s, sl, ir, c[, raw, f]) of each light, cb unused
                terms = [(None,) + pt[:5] for pt in parts] if self.ggx else [pt[:1] + pt[4:9] + pt[10:] for pt in parts]
                terms = (terms, [])  # (and each light's shading, for jac_general)
                design[:, 1] = box(_rig_diffuse(dT, rl, n, h, rig_arr, *terms))
            active = ~cens
            coef, Q = np.zeros(design.shape[1]), None
            if not np.isfinite(design).all():
                # the model overflows (a plane seen edge-on, a lobe run off): residuals MINPACK rejects
                r = np.full(len(yn), _NOT_FINITE_RESIDUAL)
                state.update(key=key, n=n, dns=dns, h=h, rough=rough, parts=parts, terms=terms, coef=coef,
                             active=active, r=r, Q=None)
                return (r, np.zeros((len(yn), 4))) if grad else (r, None)
            target = np.where(cens, self.clipn, yn)
            # the sensor reads min(model, clip): where the model clips, any value (noise, JPEG ringing) is the clip's
            free = ~cens if self.lower is not None else np.zeros(len(yn), bool)
            for _ in range(3):  # the active set of the censored rows: two updates settle it
                coef, Q = self._linear_part(active, target, w)
                model = design @ coef
                new_active = free | (model < self.clipn)
                if np.array_equal(new_active, active):
                    break
                active, Q = new_active, None  # (Q: the basis of the active set before)
            r = np.where(active, model - target, self.clipn - target)
            state.update(key=key, n=n, dns=dns, h=h, rough=rough, parts=parts, terms=terms, coef=coef,
                         active=active, r=r, Q=Q, w=w)
        if not grad:
            return state["r"], None
        return state["r"], self.jac_general(p, nb, e1, e2, state["dns"], w)

    def _background_basis(self, active, w):
        """``(QT, R, om)``: the row weights ``om`` (``w`` on active rows, 0 elsewhere; None: all 1) and the
        QR of the weighted background, kept for :data:`_BASES_KEPT` active sets (a solve goes back and forth)."""
        hit = self.lin.get(key := active.tobytes())
        if hit is None or hit[0] is not w:
            om = None if w is None and active.all() else np.where(active, 1.0 if w is None else w, 0.0)
            QT, R = _qr_rows(self.design.T[-3:] if om is None else self.design.T[-3:] * om, om is not None)
            hit = self.lin[key] = (w, QT, R, om)
            self.lin = dict(list(self.lin.items())[-_BASES_KEPT:])  # (the oldest out)
        return hit[1:]

    def _linear_part(self, active, target, w):
        """The linear parameters on the active rows, weighted by ``w``, and the columns' orthonormal basis
        (rows, the background's first); ``lstsq``'s minimum norm and no basis where a column is (nearly)
        in the others' span."""
        QT, R, om = self._background_basis(active, w)
        k = self.design.shape[1] - 3
        A, t = (self.design.T[:k], target) if om is None else (self.design.T[:k] * om, target * om)
        QkT, Rk = _qr_rows(A - (A @ QT.T) @ QT, True)
        d = np.abs(np.concatenate([np.diag(R), np.diag(Rk)]))
        if not d.min() > 1e-10 * d.max():
            return np.linalg.lstsq(self.design if om is None else self.design * om[:, None], t, rcond=None)[0], None
        g = np.linalg.solve(Rk, QkT @ t)
        return np.concatenate([g, np.linalg.solve(R, QT @ (t - g @ A))]), np.vstack([QT, QkT])

    def jac_general(self, p, nb, e1, e2, dns, w):
        """Kaufman's Jacobian (M, 4) of :meth:`resjac_general` at its cached point."""
        st = self.state
        coef, active = st["coef"], st["active"]
        G = coef[0] * self.box(_rig_grad_ggx(self.dT, self.rl, st["n"], dns, st["h"], self.rig_arr, st["rough"],
                                             parts=st["parts"]) if self.ggx
                               else _rig_grad(self.dT, st["parts"], dns, st["h"], self.rig_arr, st["rough"], self.blinn))
        if self.diffuse:
            G[:3] += coef[1] * self.box(_rig_diffuse_grad(self.dT, self.rl, p, nb, e1, e2, self.rig_arr,
                                                          at=(st["n"], dns, *st["terms"])))
        om = self._background_basis(active, w)[2]
        Ga = G if om is None else G * om
        QA = st.get("Q") if st.get("w") is w else None  # the active columns' basis (_linear_part)
        if QA is None:
            QA = _qr_rows(self.design.T if om is None else self.design.T * om, om is not None)[0]
        Ja = Ga - (Ga @ QA.T) @ QA
        return (Ja if w is None else Ja / w).T

    def resjac_plain(self, p, nb, e1, e2, grad=True, w=None):
        """Residuals of the variable projection and their Jacobian in (a, b, log h, log n). ``w``: row weights (the
        linear part solved with them; unweighted residual and Jacobian returned)."""
        state = self.state
        QT, yt = self.basis(w)
        key = (p.tobytes(), nb.tobytes(), None if w is None else w.tobytes())
        if state.get("key") != key:
            n, dns = _normal_derivs(p, nb, e1, e2)
            h, rough = float(np.exp(p[2])), float(np.exp(p[3]))
            S, parts = _rig_value(self.dT, self.rl, n, h, self.rig_arr, rough, blinn=self.blinn)
            S = self.box(S)
            Sw = S if w is None else S * w
            St = Sw - (QT @ Sw) @ QT
            aa = float(St @ St)
            g = float(St @ yt) / aa if aa > 0 else 0.0
            rw = g * St - yt
            state.update(key=key, n=n, dns=dns, h=h, rough=rough, parts=parts, St=St, aa=aa, g=g,
                         rw=rw, r=rw if w is None else rw / w)
        if not grad:
            return state["r"], None
        return state["r"], self.jac_of(state["dns"], w, False)

    def jac_of(self, dns, w, kaufman):
        """The Jacobian (M, 4) at the point of ``state``, the normal's derivatives ``dns``; ``kaufman``: without its
        second-order term (for the covariance)."""
        st = self.state
        QT = self.basis(w)[0]
        dS = self.box(_rig_grad(self.dT, st["parts"], dns, st["h"], self.rig_arr, st["rough"], self.blinn))
        if w is not None:
            dS = dS * w
        St, aa, g = st["St"], st["aa"], st["g"]
        if not aa > 0:
            return np.zeros((len(St), 4))
        M = np.empty((4, 4))  # JT = g dS - M @ [QT; St]: the projections in one product
        M[:, :3] = (g * dS) @ QT.T
        M[:, 3] = dS @ St * (g / aa)
        if not kaufman:
            M[:, 3] += dS @ st["rw"] / aa
        JT = g * dS - M @ np.vstack([QT, St])
        return (JT if w is None else JT / w).T


def start_roughness(m: PlaneModel, n, h, given=None) -> float:
    """The start's roughness on the plane (``n``, ``h``): ``given``, else :func:`phong_start` (for GGX
    its alpha, for Blinn its exponent), cached per plane until :meth:`PlaneModel.use`."""
    key = (np.asarray(n).tobytes(), float(h), given)
    if key not in m.starts:
        rough = phong_start(m, n, h, given)
        m.starts[key] = ggx_alpha_of_phong(rough) if m.ggx else rough * BLINN_PER_PHONG if m.blinn else rough
    return m.starts[key]


def _roughness_steps(m: PlaneModel, geo, log_n, QT, yt):
    """Gauss-Newton on log n from ``log_n``, the start plane held (its :func:`_rig_geometry` ``geo``)."""
    dT, rl, rig_arr, box = m.dT, m.rl, m.rig_arr, m.box
    for _ in range(_ROUGHNESS_START_STEPS):
        rough = float(np.exp(log_n))
        S, parts = _rig_value(dT, rl, None, None, rig_arr, rough, geo)
        S, dS = box(S), box(sum(pt[3] * pt[2] for pt in parts) * rough)  # dS / d log n
        St, da = S - (QT @ S) @ QT, dS - (QT @ dS) @ QT
        aa = float(St @ St)
        if not aa > 0:
            break
        g = float(St @ yt) / aa
        r = g * St - yt
        J = g * (da - St * (float(St @ da) / aa)) - St * (float(r @ da) / aa)
        jj = float(J @ J)
        step = -float(J @ r) / jj if jj > 0 else 0.0
        if not np.isfinite(step):
            break
        log_n = float(np.clip(log_n + np.clip(step, -1.0, 1.0), *np.log(_ROUGHNESS_RANGE)))
        if abs(step) < 1e-3:
            break
    return log_n


def _roughness_cost(m: PlaneModel, geo, ln, QT, yt) -> float:
    """The start plane's variable-projection cost at roughness exp(ln) (its :func:`_rig_geometry` ``geo``)."""
    S_ = m.box(_rig_value(m.dT, m.rl, None, None, m.rig_arr, float(np.exp(ln)), geo)[0])
    St_ = S_ - (QT @ S_) @ QT
    aa_ = float(St_ @ St_)
    return float(yt @ yt - (St_ @ yt) ** 2 / aa_) if aa_ > 0 else np.inf


def phong_start(m: PlaneModel, n, h, given=None) -> float:
    """Start roughness: a log-log regression of the specular part on cos beta, then Gauss-Newton on
    log n with the plane held; under several lights, also from the best of
    :data:`_START_ROUGHNESS_GRID`, kept where it lowers the cost by :data:`_START_ROUGHNESS_GAIN`."""
    if given is not None:
        return float(given)
    # cos beta f p and f p (the lobe at n = 1 and n = 0): their ratio is cos beta (one light)
    geo = _rig_geometry(m.dT, m.rl, n, h, m.rig_arr)  # the plane's pieces, for each roughness below
    S1, parts = _rig_value(m.dT, m.rl, n, h, m.rig_arr, 1.0, geo)  # 0 where a ray misses (cb < 0)
    S0 = sum(pt[3] / pt[1] for pt in parts)  # val / cb
    S1, S0 = m.box(S1), m.box(S0)
    spec = m.y - m.b_level
    selr = (spec > 0.05 * spec.max()) & (S1 > 0)
    log_n = np.log(50.0)
    if np.count_nonzero(selr) >= 3:
        x = np.log(np.clip(S1[selr] / S0[selr], 1e-12, None))
        z = np.log(spec[selr] / S0[selr])
        xc = x - x.mean()
        den = float(xc @ xc)
        slope = float(xc @ (z - z.mean())) / den if den > 0 else np.nan  # least-squares line
        if np.isfinite(slope) and slope > 1:
            log_n = np.log(min(slope, _ROUGHNESS_RANGE[1]))
    QT, yt = m.basis(None)
    log_n = _roughness_steps(m, geo, log_n, QT, yt)
    if len(m.rig_arr[0]) > 1:
        # several lights: the ratio above is no lobe's cos beta; the steps again from the grid's least cost
        other = _roughness_steps(m, geo, min(np.log(_START_ROUGHNESS_GRID),
                                             key=lambda ln: _roughness_cost(m, geo, ln, QT, yt)), QT, yt)
        if _roughness_cost(m, geo, other, QT, yt) < _START_ROUGHNESS_GAIN * _roughness_cost(m, geo, log_n, QT, yt):
            log_n = other
    return float(np.exp(log_n))
