"""Per-case runners of the two protocols: one realisation's SeedSequence in, scored :class:`Row` s out.

A runner is built once per case (cached per worker) and holds what its realisations share.
``paper``: one row per realisation, reconstructed in a ROI around the known BP. ``rendered``: one
row per in-frame ground-truth highlight; each true BP is matched to the nearest detected BP within
``match_px``, else every estimator fails with ``not_detected``; each row carries the highlight's
end-to-end record (:mod:`simtest.harness.end_to_end`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from simtest.constants import MAX_SEED
from simtest.geometry.angles import angle_between_deg
from simtest.geometry.curvature import (curvature_ratio, predicted_eigenvalue_gap, predicted_pose_error_deg)
from simtest.geometry.lights import Light, LightRig
from simtest.geometry.response import SensorResponse, video_response
from simtest.geometry.cameras import PinholeCamera
from simtest.harness.end_to_end import frame_records
from simtest.harness.estimators import ORACLE_INPUTS, score
from simtest.harness.external import score_external
from simtest.harness.suite import LIGHT_AWARE_NAMES, MeshPose
from simtest.reconstruct import reconstruct, reconstruct_rois
from simtest.reconstruct.light_fits import light_aware_estimates, with_light_aware
from simtest.reconstruct.settings import ReconSettings
from simtest.render import render_scene
from simtest.scene import load_scene, with_overrides
from simtest.scene.poses import colon_pose, liver_orbit_pose
from simtest.simulate.paper import PaperSimulator

__all__ = ["make_runner", "PaperRunner", "RenderedRunner", "Row", "reconstruct_image", "render_rig",
           "mesh_pose_overrides", "curvature_between_lights", "fit_scored", "realisation_overrides"]

#: Margin of the paper protocol's ROI around the noiseless highlight, px (5 smoothing widths).
ROI_MARGIN_PX = 10

#: How far an external estimator's BP may lie from the true one on a ``paper`` case, px.
PAPER_MATCH_PX = ROI_MARGIN_PX

#: Extra per-row diagnostics carried into the results (means reported per case).
EXTRA_KEYS = ("eigenvalue_gap", "residual_px", "bp_error_px", "k1_per_mm", "k2_per_mm",
              "pose_split_deg", "iso_radius_mm", "r_k1", "r_k2", "anisotropy", "bp_distance_mm",
              "rho", "predicted_gap", "predicted_pose_deg", "false_positives", "saturated_px")


def reconstruct_image(image, K, settings: ReconSettings):
    """Detect and reconstruct every specularity of a whole image with a case's settings.

    ``full_scale`` is set to the image maximum (a rendered highlight need not saturate). Returns the
    estimates (empty for an all-dark image).
    """
    peak = float(np.max(image))
    if not peak > 0:
        return []
    return list(reconstruct(image, K, settings=settings.replace(full_scale=peak)))


def _extras(est) -> dict:
    out = {}
    for k, attr in (("eigenvalue_gap", "eigenvalue_gap"), ("residual_px", "fit_residual_px")):
        v = getattr(est, attr, None) if est is not None else None
        try:
            out[k] = float(v) if v is not None else float("nan")
        except (TypeError, ValueError):
            out[k] = float("nan")
    # Angle between N+ and N-: 0 when the two-fold ambiguity vanishes (right circular cone).
    out["pose_split_deg"] = float("nan")
    normals = getattr(est, "normals_paper", None) if est is not None else None
    if normals is not None and normals is not False:
        nn = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        if nn.shape[0] == 2 and np.all(np.isfinite(nn)):
            out["pose_split_deg"] = float(angle_between_deg(nn[0], nn[1]))
    return out


def _dimensionless_curvature(est, h, K) -> dict:
    """Isophote radius and curvature x radius at a rendered BP (diagnostics; rho governs the error).

    ``r = sqrt(a b) d cos(phi)^1.5 / f`` from the fitted ellipse, ``d`` the distance to the BP and
    ``phi`` its angle off the optical axis. Returns ``iso_radius_mm``, ``r_k1``, ``r_k2`` and
    ``anisotropy`` = ``r |k1 - k2|`` (NaN if unknown).
    """
    nan = float("nan")
    out = {"iso_radius_mm": nan, "r_k1": nan, "r_k2": nan, "anisotropy": nan}
    ell = getattr(est, "ellipse", None) if est is not None else None
    if ell is None:
        return out
    a, b = (float(x) for x in ell.semi_axes)
    bp = np.asarray(h.bp_mm, dtype=np.float64)
    d = float(np.linalg.norm(bp))
    if not (d > 0 and a > 0 and b > 0):
        return out
    cos_phi = bp[2] / d
    r = math.sqrt(a * b) * d * cos_phi**1.5 / float(K[0, 0])
    k1, k2 = float(getattr(h, "k1", nan)), float(getattr(h, "k2", nan))
    out.update(iso_radius_mm=r, r_k1=r * k1, r_k2=r * k2, anisotropy=r * abs(k1 - k2))
    return out


def _curvature_prediction(h) -> dict:
    """``bp_distance_mm``, ``rho`` and the ``predicted_gap`` and ``predicted_pose_deg`` it predicts
    (:func:`simtest.geometry.curvature.curvature_ratio`; NaN where the curvatures are unknown).
    """
    d = float(np.linalg.norm(np.asarray(h.bp_mm, dtype=np.float64)))
    rho = curvature_ratio(float(getattr(h, "k1", float("nan"))), float(getattr(h, "k2", float("nan"))), d)
    return {"bp_distance_mm": d, "rho": rho, "predicted_gap": predicted_eigenvalue_gap(rho),
            "predicted_pose_deg": predicted_pose_error_deg(rho)}


@dataclass
class Row:
    """One scored highlight of a realisation.

    Attributes
    ----------
    errors : dict of str to float
        Angular error per estimator, degrees; NaN where it failed.
    causes : dict of str to (str or None)
        Failure cause per estimator (:data:`simtest.reconstruct.failures.REASONS`, or
        ``exception:<type>``); None where it succeeded.
    extras : dict of str to float
        Diagnostics (:data:`EXTRA_KEYS`); a key missing counts as NaN.
    e2e : dict or None
        A rendered highlight's end-to-end record (:func:`simtest.harness.end_to_end.frame_records`).
    """

    errors: dict[str, float]
    causes: dict[str, str | None]
    extras: dict[str, float] = field(default_factory=dict)
    e2e: dict | None = None


def _row(errs: dict, extras: dict) -> Row:
    return Row(errors={k: v[0] for k, v in errs.items()}, causes={k: v[1] for k, v in errs.items()}, extras=extras)


class PaperRunner:
    """Runs realisations of a ``paper`` case (:mod:`simtest.simulate.paper`).

    Parameters
    ----------
    case : simtest.harness.suite.Case
        A ``paper`` case (its ``paper`` parameters and ``recon`` settings).
    estimators : sequence of str
        Keys of :data:`simtest.harness.estimators.ESTIMATORS`.
    """

    protocol = "paper"

    def __init__(self, case, estimators, external=()) -> None:
        self.settings = case.recon
        self.sim = PaperSimulator(case.paper)
        self.estimators = tuple(estimators)
        self.external = dict(external)
        self.builtin = tuple(e for e in self.estimators if e not in self.external)
        # a fixed light: every realisation has the same noiseless image and BP, so the same ROI
        fixed = self.sim.fixed
        self._fixed = None if fixed is None else (fixed[0], self.roi(*fixed))

    def roi(self, clean: np.ndarray, bp_px) -> tuple[int, int, int, int]:
        """The "given region of interest containing the specularity" (paper section 2.3).

        The bounding box of the noiseless image above half the lowest isovalue, extended to contain the
        BP, plus :data:`ROI_MARGIN_PX`, clipped to the image. A contour that leaves it is reported as cut.

        Parameters
        ----------
        clean : ndarray of shape (H, W)
            Noiseless image of the realisation.
        bp_px : array_like of shape (2,)
            Brightest point (u, v), px.

        Returns
        -------
        tuple of int
            ``(row0, row1, col0, col1)``, half-open; the whole image if nothing is above the threshold.
        """
        h, w = clean.shape
        mask = clean > 0.5 * min(self.settings.isovalues) * float(clean.max())
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        if rows.size == 0:
            return (0, h, 0, w)
        m = ROI_MARGIN_PX
        u, v = int(round(float(bp_px[0]))), int(round(float(bp_px[1])))
        return (max(0, min(rows[0], v) - m), min(h, max(rows[-1], v) + m + 1),
                max(0, min(cols[0], u) - m), min(w, max(cols[-1], u) + m + 1))

    def _roi_of(self, clean: np.ndarray, bp_px) -> tuple[int, int, int, int]:
        """:meth:`roi`, computed once for a fixed light."""
        if self._fixed is not None and clean is self._fixed[0]:
            return self._fixed[1]
        return self.roi(clean, bp_px)

    def run(self, seedseq: np.random.SeedSequence) -> list[dict]:
        """Simulate, reconstruct and score one realisation.

        Parameters
        ----------
        seedseq : numpy.random.SeedSequence
            The realisation's seed; it drives a PCG64 generator for the noise and the simulator's draws.

        Returns
        -------
        list of Row
            One row; a BP not in front of the camera fails every estimator with ``"bp_nonpositive"``.
        """
        return self.run_many([seedseq])[0]

    def run_many(self, seedseqs) -> list[list[dict]]:
        """:meth:`run` of several realisations, their reconstructions batched
        (:func:`simtest.reconstruct.reconstruct_rois`): the same rows, bit for bit.

        Parameters
        ----------
        seedseqs : sequence of numpy.random.SeedSequence
            The realisations' seeds.

        Returns
        -------
        list of list of Row
            Per realisation, its rows (as :meth:`run`).

        Raises
        ------
        Exception
            Whatever a realisation's simulation or reconstruction raises (the caller then runs
            the realisations one by one, to tell which).
        """
        truth: list = []  # per realisation (normal, BP) or None; the images are not kept

        def items():
            for seedseq in seedseqs:
                rng = np.random.Generator(np.random.PCG64(seedseq))
                try:
                    # the image is computed in the ROI only: the reconstruction reads nothing else
                    s = self.sim.sample(rng, region=self._roi_of)
                except FloatingPointError:
                    truth.append(None)
                    continue
                truth.append((s.normal, s.bp_px, self._external(s)))
                yield s.image, s.K, s.bp_px, s.region

        ests = iter(reconstruct_rois(items(), settings=self.settings))
        out = []
        for t in truth:
            if t is None:
                errs = {k: (float("nan"), "bp_nonpositive") for k in self.estimators}
                out.append([_row(errs, {k: float("nan") for k in EXTRA_KEYS})])
            else:
                normal, bp_px, external = t
                out.append([self._score(normal, bp_px, next(ests), external)])
        return out

    def _external(self, s) -> dict:
        """Each external estimator's (error, cause) on the sample's image (a pinhole, no rig)."""
        if not self.external:
            return {}
        h, w = s.image.shape[:2]
        camera = PinholeCamera(s.K, image_size=(w, h))
        return {name: score_external(spec, s.image, camera, None, None, [(s.bp_px, s.normal)],
                                     PAPER_MATCH_PX)[0] for name, spec in self.external.items()}

    def _score(self, normal, bp_px, est, external=None):
        errs = score(est, normal, self.builtin)
        errs.update(external or {})
        extras = _extras(est)
        bp = getattr(est, "bp_px", None)
        extras["bp_error_px"] = (float(np.linalg.norm(np.asarray(bp, float) - bp_px))
                                 if bp is not None else float("nan"))
        extras["k1_per_mm"] = extras["k2_per_mm"] = 0.0  # a plane
        return _row(errs, extras)


def realisation_overrides(setting, seedseq: np.random.SeedSequence) -> dict:
    """The scene overrides of one realisation of a ``rendered`` case: its seeds.

    Parameters
    ----------
    setting : simtest.harness.suite.SceneSetting
        The case's scene setting (its ``texture``).
    seedseq : numpy.random.SeedSequence
        The realisation's seed (:func:`~simtest.harness.suite.realisation_seed`).

    Returns
    -------
    dict
        ``{"render.seed": s0}``, and with ``texture = "per_realisation"`` also
        ``"material.texture_seed": s1``: ``s0`` and ``s1`` the first two 31-bit words of the
        SeedSequence (the first is that of ``generate_state(1)``, so a case that draws no texture
        renders as before).
    """
    words = seedseq.generate_state(2, np.uint32)
    over = {"render.seed": int(words[0]) & MAX_SEED}
    if setting.texture == "per_realisation":
        over["material.texture_seed"] = int(words[1]) & MAX_SEED
    return over


class RenderedRunner:
    """Runs realisations of a ``rendered`` case: Mitsuba render, detection, reconstruction.

    Parameters
    ----------
    case : simtest.harness.suite.Case
        A ``rendered`` case: ``case.scene`` changed as its ``scene_setting`` says (overrides,
        placement, :func:`mesh_pose_overrides`), reconstructed with ``recon``, scored per ``scoring``.
    estimators : sequence of str
        Keys of :data:`simtest.harness.estimators.ESTIMATORS`.

    Raises
    ------
    simtest.scene.SceneError
        If the scene file or an override is invalid.
    """

    protocol = "rendered"

    def __init__(self, case, estimators, external=()) -> None:
        self.settings = case.recon
        self.image_kind = case.scoring.image
        self.match_px = case.scoring.match_px
        self.scene_setting = case.scene_setting
        self.spec = with_overrides(load_scene(case.scene), case.scene_setting.scene_overrides(mesh_pose_overrides))
        self.estimators = tuple(estimators)
        self.external = dict(external)
        self.builtin = tuple(e for e in self.estimators if e not in self.external)
        self.variant = None

    def run(self, seedseq: np.random.SeedSequence) -> list[dict]:
        """Render, detect, reconstruct and score one realisation (matched as the module docstring says).

        Parameters
        ----------
        seedseq : numpy.random.SeedSequence
            The realisation's seed; its first 31-bit word is the render seed.

        Returns
        -------
        list of Row
            One row per in-frame highlight (see the module docstring), or one row failing with
            ``"no_highlight_in_frame"`` if there is none. Extras hold the BP error (px), the
            principal curvatures at the BP (1/mm) and the dimensionless curvature.
        """
        over = realisation_overrides(self.scene_setting, seedseq)
        result = render_scene(with_overrides(self.spec, over), seed=over["render.seed"])
        self.variant = getattr(result, "variant", None)
        if self.image_kind == "linear":  # the render's linear grey image
            image = np.asarray(result.linear)
        else:
            image = np.asarray(result.sensor)
        ests = reconstruct_image(image, result.K, self.settings)
        ok_bps = [(e, np.asarray(e.bp_px, float)) for e in ests if getattr(e, "bp_px", None) is not None]
        # Clipping: pixels at the sensor's full scale (0 for a linear float image).
        saturated = (float(np.sum(image >= np.iinfo(image.dtype).max))
                     if np.issubdtype(image.dtype, np.integer) else 0.0)
        # False positives: detections farther than match_px from every true BP (in frame or not).
        true_bps = [np.asarray(h.bp_px, float) for h in result.highlights]
        false_pos = sum(1 for _, ebp in ok_bps if all(float(np.linalg.norm(ebp - t)) > self.match_px for t in true_bps))
        # each in-frame highlight's detection: the nearest BP within match_px (from the BPs alone)
        matched = []
        for h in (h for h in result.highlights if getattr(h, "in_frame", True)):
            bp = np.asarray(h.bp_px, float)
            # the nearest, first of equals: min scans from (None, inf) keeping what is not strictly beaten
            best, dist = min([(None, math.inf)] + [(e, float(np.linalg.norm(ebp - bp))) for e, ebp in ok_bps],
                             key=lambda p: p[1])
            matched.append((h, None if dist > self.match_px else best, dist))
        light_aware = any(e in LIGHT_AWARE_NAMES for e in self.estimators)
        if light_aware:
            rig = render_rig(result)
            # the fits run on what a user's camera file describes: the video frame and its response
            response = render_response(result)
            matched = fit_scored(image if response is None else result.video, matched, result.K, rig,
                                 response=response,
                                 quadric=True if "quadric_fit" in self.estimators else None,
                                 # listed: on every scored highlight; else where the recommendation needs it
                                 cubic=True if "cubic_patch_fit" in self.estimators else None)
            for name, attr in ORACLE_INPUTS.items():
                if name in self.estimators:
                    matched = fit_on_oracle_image(name, getattr(result, attr, None), matched, result.K, rig)
        external = self._external(result, image, [(h.bp_px, h.normal) for h, _, _ in matched])
        rows = []
        for i, (h, best, dist) in enumerate(matched):
            errs = score(best, h.normal, self.builtin, light=int(getattr(h, "light", 0)))
            errs.update({name: e[i] for name, e in external.items()})
            extras = _extras(best)
            extras["bp_error_px"] = dist if best is not None else float("nan")
            extras["k1_per_mm"] = float(getattr(h, "k1", float("nan")))
            extras["k2_per_mm"] = float(getattr(h, "k2", float("nan")))
            extras.update(_dimensionless_curvature(best, h, result.K))
            extras.update(_curvature_prediction(h))
            # per image, carried by its first row (NaN on the others)
            extras["false_positives"] = float(false_pos) if not rows else float("nan")
            extras["saturated_px"] = saturated if not rows else float("nan")
            if light_aware:
                extras.update(_depth_errors(best, h, rig))
                extras.update(_sigma_coverage(best, errs))
            extras.update(curvature_between_lights(h, result.highlights))
            rows.append(_row(errs, extras))
        if not rows:
            errs = {k: (float("nan"), "no_highlight_in_frame") for k in self.estimators}
            nans = {k: float("nan") for k in EXTRA_KEYS}
            rows.append(_row(errs, nans | {"false_positives": float(false_pos), "saturated_px": saturated}))
        # what a user of `simtest render` + `simtest reconstruct` gets, per highlight (same order)
        for row, rec in zip(rows, frame_records(result, _depth_errors)):
            row.e2e = rec
        return rows

    def _external(self, result, image, truths) -> dict:
        """Each external estimator's (error, cause) per true highlight, on what a ``simtest reconstruct``
        user has: the frame the built-in fits see, camera model, light rig and sensor response.
        """
        if not self.external or not truths:
            return {}
        response = render_response(result)
        light_aware = any(e in LIGHT_AWARE_NAMES for e in self.builtin)
        if light_aware and response is not None:
            frame = result.video
        else:
            frame, response = image, (response if image is getattr(result, "video", None) else None)
        camera, rig = result.camera_model, render_rig(result)
        return {name: score_external(spec, frame, camera, rig, response, truths, self.match_px)
                for name, spec in self.external.items()}


def fit_scored(image, matched: list, camera, rig: LightRig, **kwargs) -> list:
    """The light-aware fits (:func:`~simtest.reconstruct.light_fits.with_light_aware`, ``kwargs``
    passed on) of the detections matched to the scored highlights, rejected ones too.

    Parameters
    ----------
    image : ndarray
        The image the detections were found in.
    matched : list of (highlight, SpecularityEstimate or None, float)
        Each scored highlight, its matched detection (None: not detected) and their distance, px.
    camera : array_like of shape (3, 3) or CameraModel
    rig : LightRig

    Returns
    -------
    list of (highlight, SpecularityEstimate or None, float)
        ``matched`` with each detection fitted (one matched twice is fitted once).
    """
    scored = list({id(b): b for _, b, _ in matched if b is not None}.values())
    fitted = dict(zip((id(b) for b in scored), with_light_aware(image, scored, camera, rig, fit_rejected=True,
                                                                      **kwargs)))
    return [(h, fitted[id(b)] if b is not None else None, d) for h, b, d in matched]


def fit_on_oracle_image(name: str, image, matched: list, camera, rig: LightRig) -> list:
    """``photometric_fit`` of each scored detection on an oracle image no real frame gives.

    On the specular radiance alone (``photometric_fit_on_specular``) it shows what model and geometry
    recover; on the linear radiance (``photometric_fit_on_radiance``, diffuse shading in) what the
    shading costs; the gap to ``photometric_fit`` is the sensor's.

    Parameters
    ----------
    name : str
        A key of :data:`simtest.harness.estimators.ORACLE_INPUTS`.
    image : ndarray of shape (H, W) or None
        The render's image for it (linear radiance); None: not run.
    matched : list of (highlight, SpecularityEstimate or None, float)
        As :func:`fit_scored` returns it.
    camera : array_like of shape (3, 3) or CameraModel
    rig : LightRig

    Returns
    -------
    list of (highlight, SpecularityEstimate or None, float)
        ``matched`` with each detection's ``light_aware`` holding ``name`` too.
    """
    if image is None:
        return matched
    img = np.asarray(image, dtype=np.float64)
    done: dict = {}
    out = []
    for h, b, d in matched:
        if b is not None and id(b) not in done:
            # the radiance holds the diffuse shading: the model's diffuse column is in
            r = light_aware_estimates(img, b, camera, rig, quadric=False,
                                      diffuse=name == "photometric_fit_on_radiance")["photometric_fit"]
            done[id(b)] = dataclasses.replace(b, light_aware={**(getattr(b, "light_aware", None) or {}), name: r})
        out.append((h, done[id(b)] if b is not None else None, d))
    return out


def render_rig(result) -> LightRig:
    """The light rig of a render: its own when the renderer gives one, else its point light
    (``light.falloff = "cancel"``: no falloff; ``"keep"``: inverse-square).
    """
    rig = getattr(result, "light_rig", None)
    if rig is not None:
        return rig
    falloff = "none" if result.spec.light.falloff == "cancel" else "inverse_square"
    return LightRig((Light(tuple(float(x) for x in result.light_pos), 1.0, falloff),))


def render_response(result) -> SensorResponse | None:
    """The sensor response of a render's video frame (:func:`~simtest.geometry.response.video_response`);
    None without a video frame.
    """
    return None if getattr(result, "video", None) is None else video_response(result.spec.sensor)


def _depth_errors(est, h, rig) -> dict:
    """Depth diagnostics of one scored highlight; NaN where not given.

    ``<name>_depth_err_pct``: absolute relative depth error (%) of each light-aware estimator and of
    the recommendation (truth: distance to the BP; per-light depths scored with that light's);
    ``eps_over_d``: largest light offset over that distance; ``<name>_depth_rel_sigma``; the shares
    ``cubic_patch_fit_ok_share``, ``cubic_patch_fit_misfit_share``, ``recommended_bp_ray_share``;
    ``recommended_depth_within_2sigma``: 1 where the recommended depth errs by at most twice its
    source fit's ``depth_sigma_mm``.
    """
    nan = float("nan")
    true = float(np.linalg.norm(np.asarray(h.bp_mm, dtype=np.float64)))
    out = {"isocurve_fit_depth_err_pct": nan, "photometric_fit_depth_err_pct": nan,
           "recommended_depth_err_pct": nan, "eps_over_d": nan}
    if not true > 0:
        return out
    out["eps_over_d"] = max(float(np.linalg.norm(lt.position_mm)) for lt in rig.lights) / true
    if est is None:
        return out
    light = int(getattr(h, "light", 0))
    for name, r in (getattr(est, "light_aware", None) or {}).items():
        depth = _light_depth(r, light)
        if depth is not None:
            out[f"{name}_depth_err_pct"] = 100.0 * abs(depth / true - 1.0)
        if getattr(r, "depth_rel_sigma", None) is not None:
            out[f"{name}_depth_rel_sigma"] = float(r.depth_rel_sigma)
    cubic = (getattr(est, "light_aware", None) or {}).get("cubic_patch_fit")
    if cubic is not None:
        out["cubic_patch_fit_ok_share"] = float(cubic.ok)
        out["cubic_patch_fit_misfit_share"] = float(cubic.status == "patch_misfit")
    rec = est.recommended
    out["recommended_bp_ray_share"] = float(rec.normal_from == "bp_ray")
    depth = _light_depth(rec, light)
    out["recommended_depth_within_2sigma"] = nan
    if depth is not None:
        out["recommended_depth_err_pct"] = 100.0 * abs(depth / true - 1.0)
        # the source fit's sigma, relative, so that a per-light depth of the patch takes the patch's
        src = (getattr(est, "light_aware", None) or {}).get(rec.normal_from)
        dsig, d0 = getattr(src, "depth_sigma_mm", None), getattr(src, "depth_mm", None)
        if dsig is not None and d0:
            out["recommended_depth_within_2sigma"] = float(abs(depth - true) <= 2.0 * float(dsig) * abs(depth / d0))
    return out


def _sigma_coverage(est, errs: dict) -> dict:
    """``recommended_within_2sigma`` (error at most twice ``normal_sigma_deg``) and
    ``recommended_beyond_bp_ray`` (error above the BP ray's plus sigma): 1, 0, or NaN without a sigma
    or a score (issue 39).
    """
    rec = getattr(est, "recommended", None) if est is not None else None
    sigma = getattr(rec, "normal_sigma_deg", None) if rec is not None else None
    err = errs.get("recommended", (float("nan"), None))[0]
    if sigma is None or not np.isfinite(err):
        return {"recommended_within_2sigma": float("nan"), "recommended_beyond_bp_ray": float("nan")}
    bp = errs.get("bp_ray", (float("nan"), None))[0]
    return {"recommended_within_2sigma": float(err <= 2.0 * float(sigma)),
            "recommended_beyond_bp_ray": float(err > bp + float(sigma)) if np.isfinite(bp) else float("nan")}


def curvature_between_lights(h, highlights) -> dict:
    """How much the surface's curvature changes between the specular points of two lights.

    The partner of ``h`` is the highlight of another light nearest to it in the image.

    Parameters
    ----------
    h : simtest.simulate.truth.HighlightTruth
        The highlight scored.
    highlights : sequence of HighlightTruth
        Every highlight of the render.

    Returns
    -------
    dict
        Empty without a partner; else ``specular_separation_mm`` (camera frame) and
        ``curvature_change_rel`` = ``|(k1, k2) - (k1', k2')| / max(|(k1, k2)|, |(k1', k2')|)``.
    """
    light = int(getattr(h, "light", 0))
    others = [o for o in highlights if int(getattr(o, "light", 0)) != light]
    if not others:
        return {}
    bp = np.asarray(h.bp_px, dtype=np.float64)
    o = min(others, key=lambda o: float(np.linalg.norm(np.asarray(o.bp_px, dtype=np.float64) - bp)))
    k, ko = np.array([h.k1, h.k2], dtype=np.float64), np.array([o.k1, o.k2], dtype=np.float64)
    scale = max(float(np.linalg.norm(k)), float(np.linalg.norm(ko)))
    sep = float(np.linalg.norm(np.asarray(h.bp_mm, dtype=np.float64) - np.asarray(o.bp_mm, dtype=np.float64)))
    change = float(np.linalg.norm(k - ko)) / scale if scale > 0 else 0.0
    return {"specular_separation_mm": sep, "curvature_change_rel": change}


def _light_depth(r, light: int) -> float | None:
    """An estimate's depth for light ``light``: per-light where it has one, else its one depth."""
    ld = getattr(r, "light_depths_mm", None)
    if ld is not None and 0 <= light < len(ld) and np.isfinite(ld[light]):
        return float(ld[light])
    return r.depth_mm


def mesh_pose_overrides(p: MeshPose) -> dict:
    """Scene overrides placing the camera in or around a bundled mesh (``meshes/*.ply``).

    colon (``colon_station`` s in [0, 1]): :func:`simtest.scene.poses.colon_pose`, on the centre
    line at arc length s x length, moved off it by 0.3 x the smallest wall distance of that ring,
    looking ``mesh_view_deg`` off the tangent toward the wall on the other side. liver
    (``liver_azimuth_deg``): :func:`simtest.scene.poses.liver_orbit_pose`, on a sphere
    ``mesh_distance_mm`` outside its bounding sphere at that azimuth and ``liver_elevation_deg``,
    aimed at the centre of its bounding box.

    Parameters
    ----------
    p : simtest.harness.suite.MeshPose
        The case's mesh pose; the colon is used when ``colon_station`` is not None.

    Returns
    -------
    dict
        Dotted scene overrides: ``geometry.type = "mesh"`` (which drops the base scene's geometry,
        :func:`simtest.scene.with_overrides`), ``geometry.path`` and the camera ``position_mm``, ``look_at_mm`` (world frame of the mesh,
        mm) and ``up``.

    Raises
    ------
    FileNotFoundError, ValueError
        If the bundled mesh is missing or unreadable (:func:`simtest.scene.poses.mesh_placement`).
    """
    if p.colon_station is not None:
        pose = colon_pose(p.colon_station, p.mesh_view_deg)
    else:
        pose = liver_orbit_pose(p.liver_azimuth_deg, p.liver_elevation_deg, p.mesh_distance_mm)
    return {"geometry.type": "mesh", "geometry.path": pose.path,
            **{f"camera.{k}": v for k, v in pose.camera_keys().items()}}


def make_runner(case, estimators, external=()):
    """The runner of ``case.protocol``.

    Parameters
    ----------
    case : simtest.harness.suite.Case
        The case.
    estimators : sequence of str
        Keys of :data:`simtest.harness.estimators.ESTIMATORS`, and the names of ``external``.
    external : sequence of (str, str)
        External estimators, ``(name, "package.module:function")``
        (:mod:`simtest.harness.external`).

    Returns
    -------
    PaperRunner or RenderedRunner

    Raises
    ------
    ValueError
        If the protocol is neither ``"paper"`` nor ``"rendered"``.
    """
    if case.protocol == "paper":
        return PaperRunner(case, estimators, external)
    if case.protocol == "rendered":
        return RenderedRunner(case, estimators, external)
    raise ValueError(f"unknown protocol {case.protocol!r}")
