"""A colon with haustral folds, taeniae and haustra, and exact curvature (:func:`build_haustral_colon`).

In its parameters ``v`` (along the colon, mm) and ``theta`` (around it, rad) the wall is

    X(v, theta) = c(u) + r(v, theta) (cos theta e1(u) + sin theta e2(u)),   u = v + delta(theta)

- ``c(u)``: the centre line (two seeded sinusoids across ``z = u``), ``T`` its unit tangent and
  ``(e1, e2)`` a rotation-minimising frame (Bishop 1975; Wang et al. 2008, ACM TOG 27(1)),
  ``e1' = -(e1 . T') T`` integrated by RK4, ``e2 = T x e1``: unlike Frenet's it does not spin, so
  the taeniae run straight.
- ``delta(theta)`` bows and staggers the folds; ``v`` is constant along a crest, so rings follow
  the crests.
- ``r = R(u) - indent b(theta) + bulge (1 - b(theta)) (1 - cos phi(v)) / 2
  - h(v) (1 - relief b2(theta)) p(phi(v))``: ``R`` varies slowly; ``b`` is 1 on each of the three
  taeniae (``b2`` twice as wide), where the wall is pulled in and folds nearly vanish; haustra
  bulge between; ``p`` is the fold profile in the phase ``phi`` (crests at ``phi = 0 mod 2 pi``),
  ``exp(-x^2 / (2 s^2) - x^4 q)``, ``x = (S / pi) sin(phi / 2)``, ``s^2 = h0 rho`` (crest radius
  about ``rho``), ``q`` setting the thickness at half height, rescaled to [0, 1].

The surface is written once with second-order jets (:mod:`~simtest.scene.meshes.jet`): exact
derivatives, no step size; the only approximation is the frame's integration (below 1e-12). Normal
``X_v x X_theta / |.|`` into the lumen, curvatures in the sign convention of
:mod:`simtest.scene.meshes`. Defaults and their sources: :class:`~simtest.scene.meshes.params.HaustralParams`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import trimesh

from simtest.scene.meshes.colon import _Meander, _tube
from simtest.scene.meshes.curvature import curvature_from_derivatives
from simtest.scene.meshes.files import _generator_record
from simtest.scene.meshes.jet import Jet, compose, constant, variable
from simtest.scene.meshes.params import HaustralParams, MeshError, _check_seed, _make_params, _rng

__all__ = ["HaustralColon", "build_haustral_colon", "haustral_pose"]

#: Step of the stored rotation-minimising frame, mm (RK4 local error ~ (kappa h)^5: below 1e-12).
_FRAME_STEP_MM = 0.5
#: Margin of the frame's range beyond the parameters the surface reaches, mm.
_FRAME_MARGIN_MM = 20.0


class HaustralColon(_Meander):
    """Closed form of the haustral colon for one parameter set and seed (module notes).

    Parameters
    ----------
    p : HaustralParams
    seed : int
    """

    def __init__(self, p: HaustralParams, seed: int) -> None:
        rng = _rng(seed, "colon_haustral")
        # Draw order is part of the format: do not reorder.
        (psi_x, psi_y, self.taenia_phase, self.diam_phase, self.fold_phase,
         self.jitter_phase, self.height_phase) = rng.uniform(0.0, 2.0 * math.pi, size=7)
        super().__init__(p, psi_x, psi_y)
        self.r0 = 0.5 * p.diameter_mm
        # taenia bands: exp(kappa (cos 3 dtheta - 1)) at half height over the width's angle
        half = 0.5 * p.taenia_width_mm / self.r0
        self.kappa_b = 2.0 * math.log(2.0) / (9.0 * half * half)
        self.kappa_b2 = self.kappa_b / 4.0  # twice as wide
        # fold profile: crest curvature h0 / s^2 = 1 / rho; quartic for the half-height width
        self.s2 = max(p.fold_height_mm, 1e-9) * p.fold_crest_radius_mm
        xh = 0.5 * p.fold_thickness_mm
        self.q = max(math.log(2.0) - xh * xh / (2.0 * self.s2), 0.0) / xh**4
        xm = p.fold_spacing_mm / math.pi
        self.p_min = math.exp(-xm * xm / (2.0 * self.s2) - self.q * xm**4)
        reach = p.fold_crescent_mm + p.fold_stagger_mm
        self.u_lo = -reach - _FRAME_MARGIN_MM
        self.u_hi = p.length_mm + reach + _FRAME_MARGIN_MM
        self._nodes = np.arange(self.u_lo, self.u_hi + _FRAME_STEP_MM, _FRAME_STEP_MM)
        self._e1_nodes = self._integrate_frame()

    # -- centre line (:meth:`curve`, shared with the smooth colon) and its rotation-minimising frame --
    def tangent(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit tangent T and its derivatives T', T'' in u (closed form)."""
        _, c1, c2, c3 = self.curve(u)
        s = np.linalg.norm(c1, axis=-1, keepdims=True)
        t = c1 / s
        s1 = np.sum(t * c2, axis=-1, keepdims=True)
        t1 = (c2 - s1 * t) / s
        s2 = np.sum(t1 * c2 + t * c3, axis=-1, keepdims=True)
        t2 = (c3 - s2 * t - 2.0 * s1 * t1) / s
        return t, t1, t2

    def _rmf_rate(self, u: np.ndarray, e1: np.ndarray) -> np.ndarray:
        t, t1, _ = self.tangent(u)
        return -np.sum(e1 * t1, axis=-1, keepdims=True) * t

    def _rk4(self, u: np.ndarray, e1: np.ndarray, h: np.ndarray) -> np.ndarray:
        h = np.asarray(h, dtype=np.float64)[..., None]
        hs = h[..., 0]
        k1 = self._rmf_rate(u, e1)
        k2 = self._rmf_rate(u + 0.5 * hs, e1 + 0.5 * h * k1)
        k3 = self._rmf_rate(u + 0.5 * hs, e1 + 0.5 * h * k2)
        k4 = self._rmf_rate(u + hs, e1 + h * k3)
        return e1 + h * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0

    def _integrate_frame(self) -> np.ndarray:
        u = self._nodes
        t0, _, _ = self.tangent(u[:1])
        e = np.array([1.0, 0.0, 0.0]) - t0[0, 0] * t0[0]
        out = np.empty((len(u), 3))
        out[0] = e / np.linalg.norm(e)
        for i in range(1, len(u)):
            out[i] = self._rk4(u[i - 1:i], out[i - 1:i], np.array([u[i] - u[i - 1]]))[0]
        return out

    def frame(self, u: np.ndarray) -> tuple[np.ndarray, ...]:
        """Rotation-minimising frame at u: ``e1, e1', e1'', e2, e2', e2''`` (each u.shape + (3,)).

        Raises
        ------
        MeshError
            A parameter outside the frame's range.
        """
        u = np.asarray(u, dtype=np.float64)
        if np.any(u < self.u_lo) or np.any(u > self.u_hi) or not np.all(np.isfinite(u)):
            raise MeshError(f"HaustralColon.frame: u outside [{self.u_lo:.6g}, {self.u_hi:.6g}] mm")
        i = np.clip(((u - self.u_lo) // _FRAME_STEP_MM).astype(np.int64), 0, len(self._nodes) - 1)
        e1 = self._rk4(self._nodes[i], self._e1_nodes[i], u - self._nodes[i])
        t, t1, t2 = self.tangent(u)
        e1 = e1 - np.sum(e1 * t, -1, keepdims=True) * t  # exact orthogonality to T
        e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
        e2 = np.cross(t, e1)
        out = []
        for e in (e1, e2):
            a1 = np.sum(e * t1, -1, keepdims=True)
            out += [e, -a1 * t, -np.sum(e * t2, -1, keepdims=True) * t - a1 * t1]
        return tuple(out)

    # -- the wall --------------------------------------------------------------------------
    def _band(self, theta: Jet, kappa: float) -> Jet:
        return ((((theta - self.taenia_phase) * 3.0).cos() - 1.0) * kappa).exp()

    def fold_phase_of(self, v: Jet) -> Jet:
        """Fold phase phi(v): crests at phi = 0 mod 2 pi (increasing while jitter < 1)."""
        p = self.p
        lam2 = 2.7 * p.fold_spacing_mm
        wig = ((v * (2.0 * math.pi / lam2)) + self.jitter_phase).sin()
        return v * (2.0 * math.pi / p.fold_spacing_mm) + self.fold_phase + wig * (p.fold_jitter * lam2 / p.fold_spacing_mm)

    def _radius(self, v: Jet, theta: Jet, u: Jet) -> Jet:
        p = self.p
        b, b2 = self._band(theta, self.kappa_b), self._band(theta, self.kappa_b2)
        radius = (((u * (2.0 * math.pi / p.diameter_wavelength_mm)) + self.diam_phase).sin()
                  * (p.diameter_variation * self.r0) + self.r0)
        phi = self.fold_phase_of(v)
        x = (phi * 0.5).sin() * (p.fold_spacing_mm / math.pi)
        x2 = x.square()
        prof = ((x2 * (-0.5 / self.s2)) - x2.square() * self.q).exp()
        prof = (prof - self.p_min) * (1.0 / (1.0 - self.p_min))
        height = ((v * (2.0 * math.pi / (3.3 * p.fold_spacing_mm)) + self.height_phase).sin()
                  * p.fold_height_variation + 1.0) * p.fold_height_mm
        bulge = (1.0 - b) * (1.0 - phi.cos()) * (0.5 * p.haustra_bulge_mm)
        fold = height * (1.0 - b2 * p.taenia_fold_relief) * prof
        return radius - b * p.taenia_indent_mm + bulge - fold

    def shift(self, theta: Jet) -> Jet:
        """delta(theta): the folds' offset along the centre line (crescent and stagger), mm."""
        p = self.p
        b2 = self._band(theta, self.kappa_b2)
        return (theta - self.taenia_phase).sin() * p.fold_stagger_mm - (1.0 - b2) * p.fold_crescent_mm

    def surface_jet(self, v: np.ndarray, theta: np.ndarray) -> Jet:
        """X(v, theta) with its exact first and second derivatives (jet in a = v, b = theta)."""
        jv, jt = variable(v, "a"), variable(theta, "b")
        u = jv + self.shift(jt)
        c, c1, c2, _ = self.curve(u.v)
        e1, e11, e12, e2, e21, e22 = self.frame(u.v)
        jc = compose(u, c, c1, c2)
        je1, je2 = compose(u, e1, e11, e12), compose(u, e2, e21, e22)
        r = self._radius(jv, jt, u)
        d = je1 * jt.cos().vec() + je2 * jt.sin().vec()
        return jc + d * r.vec()

    def surface(self, v: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """X(v, theta) only (mm), broadcasting v and theta: the finite-difference test oracle's input."""
        return self.surface_jet(np.asarray(v, np.float64), np.asarray(theta, np.float64)).v

    def ring_parameters(self) -> np.ndarray:
        """Ring positions v_i: equally spaced in wall length + weight * profile turning angle."""
        p = self.p
        v = np.linspace(0.0, p.length_mm, 40 * p.n_along + 1)
        theta = self.taenia_phase + np.array([math.pi / 3.0, math.pi, 5.0 * math.pi / 3.0])
        jv = variable(v[:, None], "a")
        jt = constant(np.broadcast_to(theta[None, :], (len(v), 3)))
        r = self._radius(jv, jt, jv + self.shift(jt))
        wall = np.sqrt(1.0 + r.a * r.a).mean(axis=1)
        turning = (np.abs(r.aa) / (1.0 + r.a * r.a)).mean(axis=1)
        w = wall + p.ring_curvature_weight_mm * turning
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(v))])
        return np.interp(np.linspace(0.0, cum[-1], p.n_along), cum, v)


def build_haustral_colon(seed: int, **params: Any) -> trimesh.Trimesh:
    """Build a seeded colon with semilunar folds, three taeniae and haustra, normals facing the lumen.

    Parameters
    ----------
    seed : int
        Root seed (>= 0; SeedSequence([seed, 1003])): the centre line's, taeniae's, diameter's,
        fold spacing's and fold height's phases.
    **params
        Fields of :class:`~simtest.scene.meshes.params.HaustralParams` (lengths in mm).

    Returns
    -------
    trimesh.Trimesh
        ``n_along * n_around`` vertices (ring i is the fold-aligned curve ``v = v_i``), open at both
        ends, normals into the lumen, ``vertex_attributes["k1"]``, ``["k2"]`` (1/mm, exact),
        ``metadata["generator"]`` and ``metadata["centerline"]`` (per ring: ``v``, ``points``,
        ``tangents``, ``radius_min_mm``, ``radius_max_mm``).

    Raises
    ------
    MeshError
        Unknown or out-of-range parameter, or a bad seed; the message names it.
    """
    seed = _check_seed(seed, "build_haustral_colon")
    p: HaustralParams = _make_params(HaustralParams, params, "build_haustral_colon")
    colon = HaustralColon(p, seed)
    v = colon.ring_parameters()
    theta = np.arange(p.n_around) * (2.0 * math.pi / p.n_around)
    x = colon.surface_jet(v[:, None], theta[None, :])
    nrm, k1, k2 = curvature_from_derivatives(x.a, x.b, x.aa, x.ab, x.bb)
    centre, c1, _, _ = colon.curve(v)
    mesh, radii = _tube(x.v, nrm, k1, k2, centre)
    mesh.metadata["generator"] = {
        **_generator_record("colon_haustral", seed, p), "function": "simtest.scene.meshes.build_haustral_colon",
        "curvature": "closed form; exact derivatives by second-order forward automatic differentiation (jets); "
                     "k positive where the surface bends away from its normal"}
    mesh.metadata["centerline"] = {"v": v.tolist(), "points": centre.tolist(),
                                   "tangents": (c1 / np.linalg.norm(c1, axis=-1, keepdims=True)).tolist(), **radii}
    return mesh


_colon = functools.lru_cache(maxsize=8)(HaustralColon)  # once per mesh: its poses share the frame (~0.4 s)


def haustral_pose(source: trimesh.Trimesh | Mapping[str, Any], v_mm: float, view_deg: float, azimuth_deg: float = 0.0,
                  radial_offset: float = 0.3, look_mm: float = 20.0) -> dict[str, list[float]]:
    """A colonoscope's pose in a haustral colon: on the centre line, looking down it or at the wall.

    At ``u = v_mm`` the camera looks along ``cos(view) T + sin(view) r``, ``r = cos(az) e1 + sin(az) e2``,
    from ``c(u) - radial_offset R r`` (R the mean lumen radius); the image's up is ``T x r`` made
    perpendicular to the view.

    Parameters
    ----------
    source : trimesh.Trimesh or dict
        A mesh from :func:`build_haustral_colon` or its ``metadata["generator"]`` record.
    v_mm : float
        Position along the centre line, mm, within [0, length_mm].
    view_deg : float
        Angle of the line of sight off the tangent (about 0 down the lumen, 50 to 70 at the wall).
    azimuth_deg : float
        Direction of that tilt about the tangent, degrees from e1.
    radial_offset : float
        Offset from the centre line, fraction of the mean radius.
    look_mm : float
        Distance of ``look_at_mm`` ahead of the camera.

    Returns
    -------
    dict
        The scene's camera keys ``position_mm``, ``look_at_mm``, ``up`` (lists of floats).

    Raises
    ------
    MeshError
        The source is not a haustral colon, or ``v_mm`` is outside it.
    """
    gen = source.metadata.get("generator") if isinstance(source, trimesh.Trimesh) else source
    if not isinstance(gen, Mapping) or gen.get("name") != "colon_haustral":
        raise MeshError("haustral_pose: source has no colon_haustral generator record")
    p: HaustralParams = _make_params(HaustralParams, gen["params"], "haustral_pose")
    colon = _colon(p, _check_seed(gen["seed"], "haustral_pose"))
    if not 0.0 <= v_mm <= p.length_mm:
        raise MeshError(f"haustral_pose: v_mm: {v_mm!r} is outside [0, {p.length_mm:.6g}] mm")
    u = np.array([float(v_mm)])
    c = colon.curve(u)[0][0]
    t = colon.tangent(u)[0][0]
    e1, _, _, e2, _, _ = (f[0] for f in colon.frame(u))
    az, view = math.radians(azimuth_deg), math.radians(view_deg)
    radial = math.cos(az) * e1 + math.sin(az) * e2
    forward = math.cos(view) * t + math.sin(view) * radial
    position = c - radial_offset * colon.r0 * radial
    side = np.cross(t, radial)
    up = side - (side @ forward) * forward
    up /= np.linalg.norm(up)
    return {"position_mm": [float(x) for x in position], "look_at_mm": [float(x) for x in position + look_mm * forward],
            "up": [float(x) for x in up]}
