"""Sim-to-real: statistics of a rendered endoscope frame beside real endoscopic frames.

On 8-bit RGB frames, over the lit field (BT.601 luma > :data:`DARK_LEVEL`): near-white blobs (luma >=
:data:`WHITE_LEVEL`: the wet film reflects the light's white; luma because JPEG's chroma subsampling tints
small glints) per megapixel and their area median and 90th percentile, the saturated fraction, the tissue
colour and its R - G spread outside the blobs, luma percentiles, and the detector's candidates per
megapixel (:data:`STATISTICS`, which :mod:`simtest.render.simfit` fits), plus issue 62's glint
population (:data:`GLINT_STATISTICS`, reported, not fitted). A rendered frame is resized (INTER_AREA) to
the real frames' height first. The bundled real frames are the 24 tiles of the Hyper-Kvasir banner
(``tests/data/real``, CC BY 4.0, Borgli et al., Scientific Data 7, 283, 2020,
https://doi.org/10.1038/s41597-020-00622-y); :data:`REAL_SPLIT` declares which a fit may see.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import matplotlib
import numpy as np
from skimage.measure import label

from simtest.constants import LUMA_BT601
from simtest.reconstruct.detect import default_full_scale, detect_specularities
from simtest.reconstruct.images import quiet_stderr
from simtest.reconstruct.settings import ReconSettings

matplotlib.use("Agg", force=False)
import matplotlib.pyplot as plt  # noqa: E402 - after choosing the back-end

__all__ = ["DARK_LEVEL", "SATURATED_LEVEL", "WHITE_LEVEL", "FACTOR_GOAL", "RATIO_FLOOR", "STATISTICS", "POOLED",
           "WHITE_CHANNEL_LEVEL", "SHEEN_LUMA", "GLINT_STATISTICS", "ALL_STATISTICS", "REAL_SPLIT", "SPLIT_SEED",
           "FrameStats", "lit_field", "glint_population", "split_indices", "split_tables", "banner_tiles",
           "log_ratio", "real_reference", "frame_stats", "sim_to_real_table", "sim_to_real_figure", "fit_figure",
           "frames_figure", "glint_sheet"]

#: Luma at or below which a pixel is outside the lit field (black border, field stop), 8-bit.
DARK_LEVEL = 20
#: Luma at or above this: a near-white pixel (8-bit; below 255 because JPEG rings around clipped blobs).
WHITE_LEVEL = 230
#: Luma at or above this: a saturated pixel (8-bit, JPEG margin as above).
SATURATED_LEVEL = 250
#: The sim-to-real goal: each statistic within this factor of the real frames' median.
FACTOR_GOAL = 2.0


#: The statistics of :func:`frame_stats`, in table order, with the unit each is given in.
STATISTICS = {"saturated_fraction": "fraction of the lit field",
              "candidates_per_mp": "near-white blobs per megapixel of lit field",
              "median_area_px": "px", "p90_area_px": "px",
              "tissue_r": "8-bit level", "tissue_g": "8-bit level", "tissue_b": "8-bit level",
              "colour_spread": "8-bit levels (IQR of R - G)",
              "luma_p10": "8-bit level", "luma_p50": "8-bit level", "luma_p90": "8-bit level",
              "detector_per_mp": "detector candidates per megapixel of lit field"}

#: Issue 62's white (its glint-population definitions, made outside simtest): every channel at or above
#: this 8-bit level (the film reflects white; the tissue leaves green and blue low even where red clips).
WHITE_CHANNEL_LEVEL = 250
#: Issue 62's sheen (same provenance): lit pixels with luma in [lo, hi), bright but unclipped;
#: ``hi`` is :data:`WHITE_CHANNEL_LEVEL` so that sheen and white do not overlap.
SHEEN_LUMA = (200, 250)

#: The glint population of :func:`glint_population` (issue 62's definitions), reported beside
#: :data:`STATISTICS` and not fitted (:mod:`simtest.render.simfit` fits :data:`STATISTICS`).
GLINT_STATISTICS = {"white_blobs_per_mp": "white blobs (every channel >= 250) per megapixel of lit field",
                    "white_median_area_px": "px", "white_p90_area_px": "px",
                    "white_largest_share": "fraction of the white pixels in the largest white blob",
                    "sheen_fraction": "fraction of the lit field with luma 200 to 250"}
#: Every statistic of the table, in its order.
ALL_STATISTICS = {**STATISTICS, **GLINT_STATISTICS}

#: Floor added to both sides of a ratio in :func:`log_ratio`, per statistic: about the smallest difference
#: that matters at a real frame's scale (one blob in a 280 px tile is 13 per megapixel, one px, one level).
RATIO_FLOOR = {"saturated_fraction": 1e-5, "candidates_per_mp": 10.0, "median_area_px": 0.5,
               "p90_area_px": 0.5, "tissue_r": 1.0, "tissue_g": 1.0, "tissue_b": 1.0,
               "colour_spread": 1.0, "luma_p10": 1.0, "luma_p50": 1.0, "luma_p90": 1.0,
               "detector_per_mp": 10.0, "white_blobs_per_mp": 10.0, "white_median_area_px": 0.5,
               "white_p90_area_px": 0.5, "white_largest_share": 0.01, "sheen_fraction": 1e-5}


@dataclass(frozen=True)
class FrameStats:
    """Statistics of one 8-bit RGB frame (:data:`ALL_STATISTICS`)."""

    candidates_per_mp: float
    median_area_px: float
    p90_area_px: float
    saturated_fraction: float
    tissue_rgb: tuple[float, float, float]
    areas: np.ndarray  # (n,) pixel areas of the candidates
    colour_spread: float = float("nan")
    luma_p10: float = float("nan")
    luma_p50: float = float("nan")
    luma_p90: float = float("nan")
    detector_per_mp: float = float("nan")
    glints: dict = field(default_factory=dict)  # glint_population's statistics by name
    white_areas: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (m,) white blobs' areas
    lit_px: int = 0  # pixels of the lit field

    def values(self) -> dict[str, float]:
        """The scalar statistics by name, in the order of :data:`ALL_STATISTICS`."""
        return {"saturated_fraction": self.saturated_fraction, "candidates_per_mp": self.candidates_per_mp,
                "median_area_px": self.median_area_px, "p90_area_px": self.p90_area_px,
                "tissue_r": self.tissue_rgb[0], "tissue_g": self.tissue_rgb[1],
                "tissue_b": self.tissue_rgb[2], "colour_spread": self.colour_spread,
                "luma_p10": self.luma_p10, "luma_p50": self.luma_p50, "luma_p90": self.luma_p90,
                "detector_per_mp": self.detector_per_mp,
                **{k: float(self.glints.get(k, float("nan"))) for k in GLINT_STATISTICS}}


def lit_field(frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """BT.601 luma (H, W) of an 8- or 16-bit RGB frame (H, W, 3), float64, and its lit field, luma above
    :data:`DARK_LEVEL` (scaled by ``full / 255`` for a deeper frame): the pixels every statistic here counts."""
    f = np.asarray(frame)
    lum = f.astype(np.float64) @ LUMA_BT601
    return lum, lum > DARK_LEVEL * (np.iinfo(f.dtype).max / 255.0)


def glint_population(frame: np.ndarray) -> tuple[dict[str, float], np.ndarray, np.ndarray]:
    """Issue 62's glint population of an RGB frame (8 or 16 bit), inside the lit field.

    White: every channel >= :data:`WHITE_CHANNEL_LEVEL`; sheen: luma in :data:`SHEEN_LUMA`; lit: luma >
    :data:`DARK_LEVEL` (8-bit levels, scaled by ``full / 255`` for a deeper frame).

    Parameters
    ----------
    frame : ndarray of shape (H, W, 3), uint8 or uint16

    Returns
    -------
    stats : dict
        :data:`GLINT_STATISTICS` by name (8-connected white blobs; areas 0 and largest share NaN without one).
    areas : ndarray of shape (m,)
        The white blobs' areas (px), in label order.
    centroids : ndarray of shape (m, 2)
        Their centroids (x, y), px.

    Raises
    ------
    ValueError
        If ``frame`` is not (H, W, 3) uint8 or uint16, or has no lit pixel.
    """
    f = np.asarray(frame)
    if f.ndim != 3 or f.shape[2] != 3 or f.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"glint_population: expected an (H, W, 3) uint8 or uint16 frame, got {f.shape} {f.dtype}")
    scale = np.iinfo(f.dtype).max / 255.0
    lum, lit = lit_field(f)
    n_lit = int(lit.sum())
    if n_lit == 0:
        raise ValueError("glint_population: the frame has no lit pixel (all luma <= DARK_LEVEL)")
    white = np.all(f >= WHITE_CHANNEL_LEVEL * scale, axis=2) & lit
    _, _, st, cen = cv2.connectedComponentsWithStats(white.view(np.uint8), connectivity=8)
    areas = st[1:, cv2.CC_STAT_AREA].astype(np.float64)
    sheen = lit & (lum >= SHEEN_LUMA[0] * scale) & (lum < SHEEN_LUMA[1] * scale)
    med, p90 = _pooled_areas([areas])
    stats = {"white_blobs_per_mp": len(areas) / (n_lit / 1e6), "white_median_area_px": med, "white_p90_area_px": p90,
             "white_largest_share": float(areas.max() / areas.sum()) if len(areas) else float("nan"),
             "sheen_fraction": float(sheen.sum() / n_lit)}
    return stats, areas, cen[1:].astype(np.float64)


def _detector_count(frame: np.ndarray) -> int:
    """Components simtest's detector finds with ``ReconSettings.for_frames()``, uncapped."""
    st = ReconSettings.for_frames()
    fs = default_full_scale(frame)
    det = detect_specularities(frame, brightness_rel=st.brightness_rel, full_scale=fs,
                               saturation_level=st.saturation_level, min_area_px=st.min_area_px,
                               smooth_sigma_px=None, method=st.detection, peak_rel=st.peak_rel,
                               max_candidates=None)  # (None: the smoothing chosen from the frame's noise)
    return det.n_components


def frame_stats(frame: np.ndarray, *, detector: bool = True) -> FrameStats:
    """Statistics of an 8-bit RGB frame (module docstring).

    Parameters
    ----------
    frame : ndarray of shape (H, W, 3), uint8
    detector : bool
        Run simtest's detector for ``detector_per_mp`` (NaN without).

    Raises
    ------
    ValueError
        If ``frame`` is not (H, W, 3) uint8 or has no lit pixel.
    """
    f = np.asarray(frame)
    if f.ndim != 3 or f.shape[2] != 3 or f.dtype != np.uint8:
        raise ValueError(f"frame_stats: expected an (H, W, 3) uint8 frame, got {f.shape} {f.dtype}")
    lum, lit = lit_field(f)
    if not lit.any():
        raise ValueError("frame_stats: the frame has no lit pixel (all luma <= DARK_LEVEL)")
    white = (lum >= WHITE_LEVEL) & lit
    sat = (lum >= SATURATED_LEVEL) & lit
    lab = label(white, connectivity=2)
    areas = np.bincount(lab.ravel())[1:].astype(np.float64)
    mp = lit.sum() / 1e6
    tissue = lit & ~white
    if tissue.any():
        px = f[tissue].astype(np.float64)
        rgb = np.median(px, axis=0)
        q25, q75 = np.percentile(px[:, 0] - px[:, 1], [25, 75])
        spread = float(q75 - q25)
    else:
        rgb, spread = np.full(3, np.nan), float("nan")
    p10, p50, p90 = (float(x) for x in np.percentile(lum[lit], [10, 50, 90]))
    glints, white_areas, _ = glint_population(f)
    area_med, area_p90 = _pooled_areas([areas])
    return FrameStats(candidates_per_mp=len(areas) / mp, median_area_px=area_med, p90_area_px=area_p90,
                      saturated_fraction=float(sat.sum() / lit.sum()), tissue_rgb=tuple(float(x) for x in rgb),
                      areas=areas, colour_spread=spread, luma_p10=p10, luma_p50=p50, luma_p90=p90,
                      detector_per_mp=_detector_count(f) / mp if detector else float("nan"), glints=glints,
                      white_areas=white_areas, lit_px=int(lit.sum()))


#: Statistics whose real value is pooled over the frames (blobs and lit pixels together): a median of
#: per-frame values swings with the few frames that hold most glints. The others are per-frame medians.
POOLED = ("saturated_fraction", "candidates_per_mp", "median_area_px", "p90_area_px", "detector_per_mp",
          "white_blobs_per_mp", "white_median_area_px", "white_p90_area_px", "sheen_fraction")


def _pooled_areas(areas: list[np.ndarray]) -> tuple[float, float]:
    """Median and 90th percentile of the areas pooled over frames, px (0 and 0 without a blob)."""
    a = np.concatenate(areas) if areas else np.zeros(0)
    return (float(np.median(a)), float(np.percentile(a, 90))) if len(a) else (0.0, 0.0)


def real_reference(frames: list[np.ndarray], stats: list[FrameStats] | None = None) -> dict[str, float]:
    """The real frames' value of each statistic: pooled over the frames for :data:`POOLED`, else the median.

    Parameters
    ----------
    frames : list of ndarray of shape (h, w, 3), uint8
    stats : list of FrameStats, optional
        Their :func:`frame_stats`, if already computed.
    """
    st = stats if stats is not None else [frame_stats(f) for f in frames]
    lit_mp = np.array([s.lit_px / 1e6 for s in st])
    vals = [s.values() for s in st]
    out = {}
    for k in ALL_STATISTICS:
        v = np.array([x[k] for x in vals], dtype=np.float64)
        out[k] = float(np.nanmedian(v)) if np.isfinite(v).any() else float("nan")
    total = lit_mp.sum()
    out["saturated_fraction"] = float(sum(s.saturated_fraction * m for s, m in zip(st, lit_mp)) / total)
    out["candidates_per_mp"] = float(sum(len(s.areas) for s in st) / total)
    out["detector_per_mp"] = float(np.nansum([s.detector_per_mp * m for s, m in zip(st, lit_mp)]) / total)
    out["median_area_px"], out["p90_area_px"] = _pooled_areas([s.areas for s in st])
    out["white_blobs_per_mp"] = float(sum(len(s.white_areas) for s in st) / total)
    out["white_median_area_px"], out["white_p90_area_px"] = _pooled_areas([s.white_areas for s in st])
    out["sheen_fraction"] = float(sum(s.glints["sheen_fraction"] * m for s, m in zip(st, lit_mp)) / total)
    return out


def log_ratio(key: str, value: float, reference: float) -> float:
    """``log((value + floor) / (reference + floor))`` with the statistic's :data:`RATIO_FLOOR`."""
    fl = RATIO_FLOOR[key]
    return float(np.log((value + fl) / (reference + fl)))


def _read_rgb(path: str | Path) -> np.ndarray:
    """An image file as an RGB uint8 frame (H, W, 3); ValueError naming the file if it is not a readable image."""
    with quiet_stderr():  # libpng's own lines: the error names the file
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def banner_tiles(path: str | Path, tile_px: int = 280) -> list[tuple[str, np.ndarray]]:
    """The ``tile_px`` square tiles of a banner, row by row, as ``("<file>:r<row>c<col>", RGB uint8)``.

    Raises
    ------
    ValueError
        If the file cannot be read as an image.
    """
    img = _read_rgb(path)
    H, W = img.shape[:2]
    name = Path(path).name
    return [(f"{name}:r{r // tile_px}c{c // tile_px}", img[r:r + tile_px, c:c + tile_px].copy())
            for r in range(0, H - tile_px + 1, tile_px) for c in range(0, W - tile_px + 1, tile_px)]


#: The declared split of the bundled real frames: ``"tuning"`` (a fit may see it) or ``"held_out"``. Each
#: 280 px tile of the Hyper-Kvasir banner is one whole frame; tuning is the even columns, the split
#: scenes/colonoscope_fitted.toml was fitted with (a new split would need that scene refitted).
REAL_SPLIT: dict[str, str] = {f"hyperkvasir_banner.jpg:r{r}c{c}": "tuning" if c in (0, 2, 4, 6) else "held_out"
                              for r in range(3) for c in range(8)}
#: Seed of the split of frames :data:`REAL_SPLIT` does not list (:func:`split_indices`).
SPLIT_SEED = 62


def split_indices(ids: list[str]) -> tuple[list[int], list[int]]:
    """Indices of the tuning and the held-out frames among frames named ``ids``.

    A frame :data:`REAL_SPLIT` lists goes where it says. The others (frames the project does not
    bundle) are ordered by a permutation drawn from ``numpy.random.default_rng(SPLIT_SEED)`` and
    split half and half (the odd one to tuning); a lone frame is tuning only.

    Parameters
    ----------
    ids : list of str
        One id a frame (:func:`banner_tiles`'s for a banner's tiles, else the file name).

    Returns
    -------
    tuning, held_out : list of int
        Indices into ``ids``, each in increasing order.
    """
    tuning = [i for i, k in enumerate(ids) if REAL_SPLIT.get(k) == "tuning"]
    held = [i for i, k in enumerate(ids) if REAL_SPLIT.get(k) == "held_out"]
    rest = [i for i, k in enumerate(ids) if k not in REAL_SPLIT]
    order = [rest[j] for j in np.random.default_rng(SPLIT_SEED).permutation(len(rest))]
    n = (len(order) + 1) // 2
    return sorted(tuning + order[:n]), sorted(held + order[n:])


def at_height(frame: np.ndarray, height_px: int) -> np.ndarray:
    """``frame`` resized to ``height_px`` rows (aspect kept), area averaging."""
    H, W = frame.shape[:2]
    w = max(1, int(round(W * height_px / H)))
    return cv2.resize(frame, (w, height_px), interpolation=cv2.INTER_AREA)


def sim_to_real_table(rendered: np.ndarray, real: list[np.ndarray], *, rendered_stats: FrameStats | None = None,
                      real_stats: list[FrameStats] | None = None) -> list[dict]:
    """Compare a rendered frame with real frames, statistic by statistic.

    Parameters
    ----------
    rendered : ndarray of shape (H, W, 3), uint8
        The rendered frame (resized to the real frames' height first).
    real : list of ndarray of shape (h, w, 3), uint8
        Real frames of one height.
    rendered_stats, real_stats : optional
        :func:`frame_stats` of the resized rendered frame and of the real frames, if already computed.

    Returns
    -------
    list of dict
        One row per statistic: ``statistic``, ``fitted``, ``rendered``, ``real`` (:func:`real_reference`),
        ``real_pooled``, ``real_q25``, ``real_q75`` (per-frame quartiles), ``ratio`` (rendered / real; NaN if
        real is 0 or NaN) and ``within_goal`` (ratio within :data:`FACTOR_GOAL`).
    """
    h = real[0].shape[0]
    sim = (rendered_stats or frame_stats(at_height(rendered, h))).values()
    real_st = real_stats if real_stats is not None else [frame_stats(f) for f in real]
    ref = real_reference(real, real_st)
    reals = [s.values() for s in real_st]
    rows = []
    for key, value in sim.items():
        vals = np.array([r[key] for r in reals], dtype=np.float64)
        med = ref[key]
        ratio = value / med if med > 0 else float("nan")
        q25, q75 = np.nanpercentile(vals, [25, 75]) if np.isfinite(vals).any() else (np.nan, np.nan)
        rows.append({"statistic": key, "fitted": key in STATISTICS, "rendered": float(value), "real": med,
                     "real_pooled": key in POOLED, "real_q25": float(q25), "real_q75": float(q75),
                     "ratio": ratio,
                     "within_goal": bool(np.isfinite(ratio) and 1 / FACTOR_GOAL <= ratio <= FACTOR_GOAL)})
    return rows


def split_tables(rendered: np.ndarray, real: list[np.ndarray], tuning: list[int],
                 held_out: list[int]) -> dict[str, list[dict]]:
    """:func:`sim_to_real_table` against all, the tuning and the held-out frames, each statistic computed once.

    Returns
    -------
    dict
        ``{"all": rows, "tuning": rows, "held_out": rows}`` (a part without frames left out).
    """
    h = real[0].shape[0]
    sim = frame_stats(at_height(rendered, h))
    st = [frame_stats(f) for f in real]
    out = {"all": sim_to_real_table(rendered, real, rendered_stats=sim, real_stats=st)}
    for name, idx in (("tuning", tuning), ("held_out", held_out)):
        if idx:
            out[name] = sim_to_real_table(rendered, [real[i] for i in idx], rendered_stats=sim,
                                          real_stats=[st[i] for i in idx])
    return out


def _show(ax, image: np.ndarray, title: str, **title_kw) -> None:
    """``image`` on ``ax`` under ``title`` (``title_kw`` to ``set_title``), without axes."""
    ax.imshow(image)
    ax.set_title(title, **title_kw)
    ax.axis("off")


def sim_to_real_figure(rendered: np.ndarray, real: list[np.ndarray], rows: list[dict]):
    """Figure: the rendered frame, six real frames, the area distributions and each statistic's ratio."""
    h = real[0].shape[0]
    sim_frame = at_height(rendered, h)
    fig = plt.figure(figsize=(12, 7.5), constrained_layout=True)
    gs = fig.add_gridspec(3, 5)
    _show(fig.add_subplot(gs[0:2, 0:2]), sim_frame,
          f"rendered ({rendered.shape[1]} x {rendered.shape[0]} px, shown at {h} px high)")
    for i, f in enumerate(real[:6]):
        _show(fig.add_subplot(gs[i // 3, 2 + i % 3]), f, f"real frame {i}", fontsize=9)
    a = fig.add_subplot(gs[2, 0:2])
    sim_areas = frame_stats(sim_frame).areas
    real_areas = np.concatenate([frame_stats(f).areas for f in real])
    bins = np.logspace(0, 4, 25)
    for areas, name in ((real_areas, f"real ({len(real)} frames)"), (sim_areas, "rendered")):
        if len(areas):  # a density of no candidates is undefined
            a.hist(areas, bins=bins, density=True, alpha=0.6, label=f"{name}, {len(areas)} candidates")
        else:
            a.plot([], [], label=f"{name}: no candidate")
    a.set_xscale("log")
    a.set_xlabel("highlight candidate area (px, at the real frames' scale)")
    a.set_ylabel("density")
    a.legend()
    b = fig.add_subplot(gs[2, 2:5])
    names = [r["statistic"] for r in rows]
    ratios = [r["ratio"] for r in rows]
    b.axhspan(1 / FACTOR_GOAL, FACTOR_GOAL, color="0.9", label=f"goal: within x{FACTOR_GOAL:g}")
    b.bar(range(len(rows)), ratios, color=["tab:green" if r["within_goal"] else "tab:red" for r in rows])
    b.set_xticks(range(len(rows)), names, rotation=30, ha="right", fontsize=8)
    b.set_yscale("log")
    b.set_ylabel("rendered / real")
    b.legend(fontsize=8)
    return fig


def fit_figure(before: np.ndarray, after: np.ndarray, fitted: list[np.ndarray], held: list[np.ndarray], tables: dict):
    """Figure of a fit: frames before and after beside real ones, and each ratio before and after.

    ``tables``: ``{"fitted": {"before": rows, "after": rows}, "held_out": {...}}`` of :func:`sim_to_real_table`.
    """
    h = fitted[0].shape[0]
    fig = plt.figure(figsize=(13, 8), constrained_layout=True)
    gs = fig.add_gridspec(2, 6)
    shown = [(at_height(before, h), "rendered, before the fit"), (at_height(after, h), "rendered, after the fit")]
    shown += [(f, f"fitted real frame {i}") for i, f in enumerate(fitted[:2])]
    shown += [(f, f"held-out real frame {i}") for i, f in enumerate(held[:2])]
    for i, (f, title) in enumerate(shown):
        _show(fig.add_subplot(gs[0, i]), f, title, fontsize=9)
    for j, name in enumerate(("fitted", "held_out")):
        if name not in tables:
            continue
        b = fig.add_subplot(gs[1, 3 * j:3 * j + 3])
        rows_b, rows_a = tables[name]["before"], tables[name]["after"]
        x = np.arange(len(rows_a))
        b.axhspan(1 / FACTOR_GOAL, FACTOR_GOAL, color="0.9", label=f"within x{FACTOR_GOAL:g}")
        b.bar(x - 0.2, [r["ratio"] for r in rows_b], 0.4, color="0.6", label="before")
        b.bar(x + 0.2, [r["ratio"] for r in rows_a], 0.4,
              color=["tab:green" if r["within_goal"] else "tab:red" for r in rows_a], label="after")
        b.set_xticks(x, [r["statistic"] for r in rows_a], rotation=35, ha="right", fontsize=8)
        b.set_yscale("log")
        n_in = sum(r["within_goal"] for r in rows_a)
        b.set_title(f"{name.replace('_', '-')} frames: {n_in} of {len(rows_a)} within x{FACTOR_GOAL:g} after",
                    fontsize=10)
        b.set_ylabel("rendered / real")
        b.legend(fontsize=8)
    return fig


def frames_figure(rendered: np.ndarray, real: list[np.ndarray], ids: list[str], tuning: list[int],
                  held_out: list[int], title: str = "rendered", per_part: int = 2):
    """Figure: the rendered frame beside the first ``per_part`` tuning and held-out real frames."""
    h = real[0].shape[0]
    shown = [(at_height(rendered, h), f"{title}\n({rendered.shape[1]} x {rendered.shape[0]} px, at {h} px high)")]
    shown += [(real[i], f"tuning frame\n{ids[i]}") for i in tuning[:per_part]]
    shown += [(real[i], f"held-out frame\n{ids[i]}") for i in held_out[:per_part]]
    fig, axes = plt.subplots(1, len(shown), figsize=(2.9 * len(shown), 3.6), constrained_layout=True, squeeze=False)
    for a, (f, t) in zip(axes[0], shown):
        _show(a, f, t, fontsize=9)
    return fig


def _largest_blob_crops(frames: list[np.ndarray], names: list[str], n: int, crop_px: int) -> list[tuple]:
    """``(crop, label)`` around the ``n`` largest white blobs of ``frames``, ``crop_px`` square, zero-padded."""
    blobs = []
    for f, name in zip(frames, names):
        _, areas, cen = glint_population(f)
        blobs += [(a, name, f, c) for a, c in zip(areas, cen)]
    blobs.sort(key=lambda b: -b[0])
    half = crop_px // 2
    out = []
    for area, name, f, (x, y) in blobs[:n]:
        pad = np.pad(f, ((half, half), (half, half), (0, 0)))
        r, c = int(round(y)) + half, int(round(x)) + half
        out.append((pad[r - half:r - half + crop_px, c - half:c - half + crop_px], f"{name}\n{area:.0f} px"))
    return out


def glint_sheet(rendered: np.ndarray, real: list[np.ndarray], ids: list[str], tuning: list[int],
                held_out: list[int], title: str = "rendered", n: int = 16, crop_px: int = 24):
    """Figure: ``crop_px`` crops around the ``n`` largest white blobs of the rendered, tuning and held-out frames."""
    h = real[0].shape[0]
    short = [k.split(":")[-1] for k in ids]
    parts = [(title, _largest_blob_crops([at_height(rendered, h)], [title], n, crop_px))]
    parts += [(name, _largest_blob_crops([real[i] for i in idx], [short[i] for i in idx], n, crop_px))
              for name, idx in (("tuning frames", tuning), ("held-out frames", held_out))]
    cols = 8
    per = max(1, -(-n // cols))
    fig, axes = plt.subplots(per * len(parts), cols, figsize=(1.25 * cols, 1.45 * per * len(parts)),
                             constrained_layout=True, squeeze=False)
    for p, (name, crops) in enumerate(parts):
        for j in range(per * cols):
            a = axes[p * per + j // cols, j % cols]
            a.set_xticks([])
            a.set_yticks([])
            if j < len(crops):
                a.imshow(crops[j][0], interpolation="nearest")
                a.set_title(crops[j][1], fontsize=6)
            else:
                a.axis("off")
            if j == 0:
                a.axis("on")
                a.set_xticks([])
                a.set_yticks([])
                a.set_ylabel(name if crops else f"{name}:\nno white blob", fontsize=8)
    fig.suptitle(f"{crop_px} px crops around the {n} largest white blobs (every channel >= "
                 f"{WHITE_CHANNEL_LEVEL}), at the real frames' scale", fontsize=9)
    return fig
