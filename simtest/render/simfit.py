"""Sim-to-real calibration: fit a scene's appearance and sensor to real frames' statistics.

``simtest simreal --fit`` adjusts a tissue scene so that the statistics of :mod:`simtest.render.simreal`
on its video frame come near the real frames'. Render parameters (each value needs a render): relief RMS
height and Hurst exponent, film roughness and its variation. Develop parameters (applied to one render's
linear images): base albedo (the diffuse part is linear in it), auto-exposure target, read noise, gamma.

The loss over the log-ratios ``r_k`` (:func:`simtest.render.simreal.log_ratio`) is
``sum_k max(0, |r_k| - log(MARGIN))^2 + SPREAD_WEIGHT sum_k r_k^2``, minimised by Nelder-Mead in two levels:
an outer search over the render parameters at a reduced film, each point running an inner search over the
develop parameters; a polish at the scene's own film; the develop parameters again, then the sensor's
alone, over :data:`RENDER_SEEDS` render seeds. Each loss pools a few sensor-noise draws. The fit sees only
the tuning frames (:func:`split_frames`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.optimize import minimize

from simtest.constants import MAX_SEED
from simtest.render.outputs import TISSUE_COVERAGE
from simtest.render.render import render_scene
from simtest.render.sensor import video_frame
from simtest.render.simreal import STATISTICS, at_height, log_ratio, real_reference, split_indices
from simtest.render.tissue import TISSUE_ALBEDO
from simtest.scene.spec import SceneSpec, with_overrides

__all__ = ["MARGIN", "SPREAD_WEIGHT", "RENDER_SEEDS", "FitResult", "develop", "fit_scene", "split_frames",
           "fit_loss", "render_seeds_of"]

#: The loss pushes every statistic inside this factor first (below the goal's 2, a margin for the film change)
MARGIN = 1.4
#: Weight of the plain squared log-ratios in the loss: small, so it only chooses among points inside the band
SPREAD_WEIGHT = 0.05

#: Bounds of the develop parameters: base albedo per channel (linear RGB), auto-exposure target and read
#: noise (fractions of full scale), display gamma.
DEVELOP_BOUNDS = {"albedo_r": (0.02, 1.0), "albedo_g": (0.005, 1.0), "albedo_b": (0.005, 1.0),
                  "auto_mean": (0.03, 0.6), "gaussian_sigma": (0.0005, 0.05), "gamma": (1.4, 3.2)}
#: The develop parameters of the sensor alone (the last stage, on the fitted albedo's render).
SENSOR_BOUNDS = {k: DEVELOP_BOUNDS[k] for k in ("auto_mean", "gaussian_sigma", "gamma")}
#: Bounds of the render parameters: relief RMS height (mm), film alpha, Hurst exponent, film log-roughness SD.
RENDER_BOUNDS = {"relief_mm": (1e-5, 0.02), "alpha": (0.005, 0.5), "relief_hurst": (0.3, 1.0),
                 "film_variation": (0.05, 2.5)}
#: Where the search starts the film's variation when the scene has none (0 is not in the log-space box)
FILM_VARIATION_START = 0.7


def split_frames(frames: list, ids: list[str] | None = None) -> tuple[list, list]:
    """(tuning, held out) frames by :func:`simtest.render.simreal.split_indices` (``ids`` None: all unlisted)."""
    names = list(ids) if ids is not None else [f"#{i}" for i in range(len(frames))]
    tuning, held = split_indices(names)
    return [frames[i] for i in tuning], [frames[i] for i in held]


def fit_loss(stats: dict[str, float], reference: dict[str, float]) -> float:
    """The fit's loss of a frame's statistics against the real reference (module notes)."""
    band = math.log(MARGIN)
    total = 0.0
    for k in STATISTICS:
        s, t = stats.get(k, float("nan")), reference.get(k, float("nan"))
        if not (np.isfinite(s) and np.isfinite(t)):
            continue
        r = log_ratio(k, s, t)
        total += max(0.0, abs(r) - band) ** 2 + SPREAD_WEIGHT * r * r
    return total


def develop(rgb: np.ndarray, specular: np.ndarray, base_albedo, params: dict, spec: SceneSpec,
            seed: int, tissue: np.ndarray | None = None) -> tuple[np.ndarray, SceneSpec]:
    """The video frame of a render with other develop parameters, and the scene that makes it.

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3), float32
        Linear RGB radiance of a tissue render.
    specular : ndarray of shape (H, W), float32
        Its specular part (the same in each channel).
    base_albedo : (3,) array_like
        The base albedo the render was made with.
    params : dict
        Develop parameters (:data:`DEVELOP_BOUNDS`); missing ones keep the scene's.
    spec : SceneSpec
        The rendered scene.
    seed : int
        Render seed (the sensor noise stream).
    tissue : ndarray of shape (H, W), bool, optional
        Pixels on tissue (:func:`simtest.render.sensor.video_frame`).

    Returns
    -------
    frame : ndarray of shape (H, W, 3), uint8
    spec : SceneSpec
        ``spec`` with the parameters set.
    """
    new = _with_develop(spec, params, base_albedo)
    gain = np.asarray(new.material.albedo, dtype=np.float32) / np.asarray(base_albedo, dtype=np.float32)
    if np.all(gain == 1.0):  # the render's own albedo: its image as it is (no round-off)
        lin = rgb
    else:
        s = specular[..., None]
        lin = (rgb - s) * gain + s
    return video_frame(lin, new.sensor, seed, tissue=tissue), new


def _with_develop(spec: SceneSpec, params: dict, base_albedo) -> SceneSpec:
    alb = tuple(float(params.get(f"albedo_{c}", base_albedo[i])) for i, c in enumerate("rgb"))
    ov = {"material.albedo": list(alb)}
    if "auto_mean" in params:
        ov["sensor.exposure_mode"] = "auto"
        ov["sensor.auto_mean"] = float(params["auto_mean"])
    if "gaussian_sigma" in params:
        ov["sensor.gaussian_sigma"] = float(params["gaussian_sigma"])
    if "gamma" in params:
        ov["sensor.tone"] = "gamma"
        ov["sensor.gamma"] = float(params["gamma"])
    return with_overrides(spec, ov)


def _to_unit(params: dict, bounds: dict) -> np.ndarray:
    """Parameters as log-position in their bounds, 0..1 (the optimiser's coordinates)."""
    return np.array([(math.log(params[k]) - math.log(lo)) / (math.log(hi) - math.log(lo))
                     for k, (lo, hi) in bounds.items()])


def _from_unit(x: np.ndarray, bounds: dict) -> dict:
    out = {}
    for xi, (k, (lo, hi)) in zip(x, bounds.items()):
        t = min(max(float(xi), 0.0), 1.0)
        out[k] = float(math.exp(math.log(lo) + t * (math.log(hi) - math.log(lo))))
    return out


def _penalty(x: np.ndarray) -> float:
    """Outside the unit box: a wall the simplex walks back from."""
    return float(np.sum(np.clip(x - 1.0, 0, None) ** 2 + np.clip(-x, 0, None) ** 2)) * 10.0


def _nelder_mead(f: Callable[[np.ndarray], float], x0: np.ndarray, maxfev: int, step: float) -> np.ndarray:
    n = len(x0)
    simplex = np.vstack([x0] + [x0 + step * np.eye(n)[i] * (1 if x0[i] < 0.5 else -1) for i in range(n)])
    res = minimize(f, x0, method="Nelder-Mead",
                   options={"maxfev": maxfev, "initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-4})
    return np.clip(res.x, 0.0, 1.0)


@dataclass
class FitResult:
    """A fit's outcome.

    Attributes
    ----------
    spec : SceneSpec
        The fitted scene.
    before, after : ndarray of shape (H, W, 3), uint8
        The video frames of the input and the fitted scene.
    params : dict
        The fitted parameters by name.
    renders : int
        Renders the fit made.
    history : list of dict
        The outer search's points: the render parameters and the loss of each.
    seed : int
        The render seed used.
    """

    spec: SceneSpec
    before: np.ndarray
    after: np.ndarray
    params: dict
    renders: int
    history: list = field(default_factory=list)
    seed: int = 0


#: Stable key of the noise draws of the fit's loss in ``SeedSequence([seed, NOISE_SEED_KEY])`` (after the
#: render's own seed, :func:`render_seeds_of`).
NOISE_SEED_KEY = 0xF17


def _pooled_stats(frames: list[np.ndarray], height: int) -> dict[str, float]:
    """Statistics of a frame's noise draws, pooled as the real frames' are (one draw's blob statistics swing)."""
    return real_reference([at_height(f, height) for f in frames])


#: Renders of the fitted scene whose losses the last develop searches add up (at one seed the fit fits
#: that render's noise)
RENDER_SEEDS = 3
#: Stable key of the extra render seeds in ``SeedSequence([seed, RENDER_SEED_KEY])``.
RENDER_SEED_KEY = 0x5EED


def render_seeds_of(seed: int, k: int, key: int = RENDER_SEED_KEY) -> list[int]:
    """The root seed, then ``k - 1`` seeds from ``SeedSequence([seed, key])``, below ``MAX_SEED``."""
    extra = np.random.SeedSequence([int(seed), key]).generate_state(max(k - 1, 0))
    return [int(seed)] + [int(x % MAX_SEED) for x in extra]


def _develop_render(res, base_albedo, params: dict, spec: SceneSpec, seed: int) -> np.ndarray:
    """:func:`develop`'s frame of a :class:`~simtest.render.render.RenderResult` (its tissue pixels metered)."""
    return develop(res.rgb, res.specular, base_albedo, params, spec, seed, res.coverage >= TISSUE_COVERAGE)[0]


def _seed_loss(develop_one: Callable, res, draws: int, height: int, ref: dict) -> float:
    """The loss of one render's frames, developed at ``draws`` noise seeds and pooled."""
    frs = [develop_one(res, sd) for sd in render_seeds_of(res.seed, draws, NOISE_SEED_KEY)]
    return fit_loss(_pooled_stats(frs, height), ref)


def _check_fit_inputs(spec: SceneSpec, frames: list, keep: tuple) -> None:
    """The checks of :func:`fit_scene` (its ``Raises``)."""
    if spec.material.model != "tissue" or spec.sensor.output != "video":
        raise ValueError(f"{spec.source}: material.model: the fit needs a tissue scene with a video "
                         f"sensor (material.model = \"tissue\", sensor.output = \"video\")")
    if not frames:
        raise ValueError("fit_scene: no real frame to fit to")
    unknown = sorted(set(keep) - set(RENDER_BOUNDS))
    if unknown:
        raise ValueError(f"fit_scene: keep: {unknown} are no render parameters ({', '.join(RENDER_BOUNDS)})")


def _starting_point(spec: SceneSpec, keep: tuple) -> tuple[tuple, dict, dict]:
    """``(base albedo, develop params, render params)`` of ``spec`` within their bounds: where the searches start."""
    mat = spec.material
    base = tuple(mat.albedo) if mat.albedo is not None else TISSUE_ALBEDO[mat.tissue]
    dev = {"albedo_r": base[0], "albedo_g": base[1], "albedo_b": base[2],
           "auto_mean": spec.sensor.auto_mean if spec.sensor.exposure_mode == "auto" else 0.2,
           "gaussian_sigma": max(spec.sensor.gaussian_sigma, 0.001),
           "gamma": spec.sensor.gamma if spec.sensor.tone == "gamma" else 2.2}
    dev = {k: min(max(v, DEVELOP_BOUNDS[k][0]), DEVELOP_BOUNDS[k][1]) for k, v in dev.items()}
    rnd = {"relief_mm": max(mat.relief_mm, 1e-5), "alpha": mat.microfacet_alpha, "relief_hurst": mat.relief_hurst,
           "film_variation": mat.film_variation if mat.film_variation > 0 else FILM_VARIATION_START}
    rnd = {k: min(max(v, RENDER_BOUNDS[k][0]), RENDER_BOUNDS[k][1]) for k, v in rnd.items()}
    if "film_variation" in keep:  # kept as it is, uniform too
        rnd["film_variation"] = mat.film_variation
    return base, dev, rnd


def _fit_sensor(fitted: SceneSpec, d: dict, rseed: int, rseeds: list, draws: int, height: int, ref: dict,
                inner_evals: int) -> tuple[np.ndarray, SceneSpec, dict, float, int]:
    """Stage 3 of :func:`fit_scene`: the sensor on the fitted scene's own renders, its own frame's loss added.

    Returns ``(frame, scene, params, loss, renders made)``.
    """
    owns = [render_scene(fitted, seed=sd) for sd in rseeds]
    own = owns[0]
    alb = fitted.material.albedo
    tissue = own.coverage >= TISSUE_COVERAGE
    start = {k: d[k] for k in SENSOR_BOUNDS}

    def f_sensor(x):
        q = _from_unit(x, SENSOR_BOUNDS)

        def dev(r, sd):
            return _develop_render(r, alb, q, fitted, sd)

        own_frame = dev(own, rseed)
        return (sum(_seed_loss(dev, r, draws, height, ref) for r in owns)
                + fit_loss(_pooled_stats([own_frame], height), ref) + _penalty(x))

    x = _nelder_mead(f_sensor, _to_unit(start, SENSOR_BOUNDS), max(10, inner_evals // 2), 0.1)
    d = {**d, **_from_unit(x, SENSOR_BOUNDS)}
    loss = f_sensor(x)
    after, fitted = develop(own.rgb, own.specular, alb, d, fitted, rseed, tissue)
    return after, fitted, d, loss, len(owns)


def fit_scene(spec: SceneSpec, frames: list[np.ndarray], *, seed: int = 0, outer_evals: int = 14,
              inner_evals: int = 60, fit_scale: float = 0.5, fit_spp: int = 4, noise_draws: int = 3,
              polish_evals: int = 6, render_seeds: int = RENDER_SEEDS, keep: tuple[str, ...] = (),
              progress: Callable[[str], None] | None = None) -> FitResult:
    """Fit the render and develop parameters of a tissue scene to real frames (module notes).

    Parameters
    ----------
    spec : SceneSpec
        A scene with ``material.model = "tissue"`` and a video sensor.
    frames : list of ndarray of shape (h, w, 3), uint8
        The real frames to fit to (one height).
    seed : int
        Root seed of every render; the fitted scene's ``render.seed``.
    outer_evals : int
        Renders of the outer search (at ``fit_scale`` of the film, ``fit_spp`` samples).
    fit_scale : float
        Film scale of the outer search's renders, (0, 1].
    fit_spp : int
        Samples per pixel of the outer search's renders.
    noise_draws : int
        Sensor-noise draws each loss pools at the scene's film (one fewer in the outer search).
    inner_evals : int
        Develop evaluations of the first inner search (fewer for the later ones).
    polish_evals : int
        Renders at the scene's own film and spp that move the reduced film's optimum (0: none).
    render_seeds : int
        Renders of the fitted scene (:func:`render_seeds_of`) whose losses the last searches add up.
    keep : tuple of str
        Render parameters (keys of :data:`RENDER_BOUNDS`) held at the scene's values.
    progress : callable, optional
        Called with a line of text after each render.

    Returns
    -------
    FitResult

    Raises
    ------
    ValueError
        If the scene is not a tissue scene with a video sensor, there is no frame, or ``keep`` names an
        unknown parameter.
    """
    _check_fit_inputs(spec, frames, keep)
    say = progress or (lambda _s: None)
    rseed = int(seed)
    height = frames[0].shape[0]
    ref = real_reference(frames)
    base, dev, rnd = _starting_point(spec, keep)
    free = {k: b for k, b in RENDER_BOUNDS.items() if k not in keep}
    kept = {k: v for k, v in rnd.items() if k in keep}

    def searched(x) -> dict:
        return {**kept, **_from_unit(x, free)}
    W, H = spec.camera.width_px, spec.camera.height_px
    small = {"camera.width_px": max(8, round(W * fit_scale)), "camera.height_px": max(8, round(H * fit_scale)),
             "render.spp": int(fit_spp)}
    state: dict = {"dev": dev, "best": {}, "renders": 0}
    history: list[dict] = []

    def with_render(s: SceneSpec, p: dict) -> SceneSpec:
        return with_overrides(s, {"material.relief_mm": p["relief_mm"], "material.alpha": p["alpha"],
                                  "material.relief_hurst": p["relief_hurst"],
                                  "material.film_variation": p["film_variation"], "material.albedo": list(base)})

    def inner(res, s: SceneSpec, start: dict, evals: int, draws: int) -> tuple[float, dict]:
        seeds = render_seeds_of(rseed, draws, NOISE_SEED_KEY)

        def f(x):
            p = _from_unit(x, DEVELOP_BOUNDS)
            frs = [_develop_render(res, base, p, s, sd) for sd in seeds]
            return fit_loss(_pooled_stats(frs, height), ref) + _penalty(x)

        x = _nelder_mead(f, _to_unit(start, DEVELOP_BOUNDS), evals, 0.15)
        return f(x), _from_unit(x, DEVELOP_BOUNDS)

    def outer(x, film: dict, evals: int, draws: int, stage: str):
        p = searched(x)
        s = with_overrides(with_render(spec, p), film)
        res = render_scene(s, seed=rseed)
        state["renders"] += 1
        loss, d = inner(res, s, state["dev"], evals, draws)
        loss += _penalty(x)
        history.append({"stage": stage, **p, **d, "loss": loss})
        best = state["best"].get(stage, (math.inf, None))
        if loss < best[0]:
            state["best"][stage] = (loss, (p, d))
            state["dev"] = d
        say(f"render {state['renders']} ({stage}): " + ", ".join(f"{k} {v:.4g}" for k, v in p.items())
            + f": loss {loss:.4g}")
        return loss

    before_res = render_scene(spec, seed=rseed)
    # 1. the search at the reduced film (later inner searches start from the best, with half the evaluations)
    first = [True]

    def coarse(x):
        evals = inner_evals if first[0] else max(10, inner_evals // 2)
        first[0] = False
        return outer(x, small, evals, max(1, noise_draws - 1), "reduced film")

    if free:
        _nelder_mead(coarse, _to_unit(rnd, free), outer_evals, 0.2)
    else:  # nothing to search: the develop parameters of the scene's render parameters
        coarse(np.zeros(0))
    p, d = state["best"]["reduced film"][1]
    # 2. the polish at the scene's film and spp (clipping and the tone curve act before the resize)
    if polish_evals > 0 and free:
        state["dev"] = d
        _nelder_mead(lambda x: outer(x, {}, max(10, inner_evals // 4), max(1, noise_draws - 1), "scene's film"),
                     _to_unit(p, free), polish_evals, 0.06)
        p, d = state["best"]["scene's film"][1]
    full = with_render(spec, p)
    rseeds = render_seeds_of(rseed, render_seeds)
    fulls = [render_scene(full, seed=sd) for sd in rseeds]
    state["renders"] += len(fulls)
    draws = max(1, noise_draws - 1) if len(fulls) > 1 else noise_draws

    def f_full(x):
        q = _from_unit(x, DEVELOP_BOUNDS)
        return sum(_seed_loss(lambda r, sd: _develop_render(r, base, q, full, sd), r, draws, height, ref)
                   for r in fulls) + _penalty(x)

    x = _nelder_mead(f_full, _to_unit(d, DEVELOP_BOUNDS), max(10, inner_evals * 2 // 3), 0.1)
    d = _from_unit(x, DEVELOP_BOUNDS)
    res = fulls[0]
    _, fitted = develop(res.rgb, res.specular, base, d, full, res.seed, res.coverage >= TISSUE_COVERAGE)
    fitted = with_overrides(fitted, {"render.seed": rseed})
    # 3. the sensor on the fitted scene's own render (_fit_sensor)
    after, fitted, d, loss, n_own = _fit_sensor(fitted, d, rseed, rseeds, draws, height, ref, inner_evals)
    state["renders"] += n_own
    fitted = dataclasses.replace(fitted, source=spec.source)
    say(f"at the scene's film ({W} x {H}, {spec.render.spp} spp): loss {loss:.4g} (render seeds "
        f"{', '.join(map(str, rseeds))}, each pooled over its noise draws, + the own frame)")
    return FitResult(spec=fitted, before=before_res.frame, after=after, params={**p, **d},
                     renders=state["renders"] + 1, history=history, seed=rseed)
