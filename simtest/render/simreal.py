"""Sim-to-real: statistics of a rendered endoscope frame beside real endoscopic frames.

A rendered frame predicts real error only if it looks like a real frame where the reconstruction
looks: how many highlights, how large, how much is clipped, what colour the tissue is. This
module measures, on 8-bit RGB frames:

- **highlight candidates per megapixel**: 8-connected components of near-white pixels (BT.601
  luma >= :data:`WHITE_LEVEL`: the wet film reflects the light's colour, so a specular highlight
  is white where the tissue is pink or red, whose luma stays lower; luma rather than every channel
  because JPEG's 4:2:0 chroma subsampling tints a glint of a few pixels with the tissue around
  it), per megapixel of the lit field (luma > :data:`DARK_LEVEL`, which leaves out the black
  border of the field stop);
- **their area distribution** (median and 90th percentile, pixels);
- **saturated fraction**: pixels with luma >= :data:`SATURATED_LEVEL`, over the lit field;
- **tissue colour**: the median R, G, B of the lit field outside the highlights, and its
  **spread**: the interquartile range of R - G there (8-bit levels);
- **intensity histogram**: the 10th, 50th and 90th percentiles of the lit field's luma;
- **detector candidates per megapixel**: the bright components simtest's own detector finds with
  its defaults for whole frames (what ``simtest reconstruct`` would examine).

The real frames' value of a glint-population statistic is pooled over the frames
(:func:`real_reference`), of the others the median over the frames.

Frames of different resolutions are compared at the real frames' scale: the rendered frame is
resized (area averaging, OpenCV's INTER_AREA) to the real frames' height first. The real frames
bundled with the project are the 24 frames of the Hyper-Kvasir banner (``tests/data/real``, CC BY
4.0, Borgli et al., Scientific Data 7, 283, 2020, https://doi.org/10.1038/s41597-020-00622-y):
280 x 280 px each, JPEG, some with burnt-in text or green boxes (which the near-white and colour
statistics partly see).

The goal is a factor 2 on each statistic between the rendered frame and the real frames
(:func:`sim_to_real_table`); :func:`sim_to_real_figure` shows the frames and the area
distributions. :mod:`simtest.render.simfit` fits a scene to real frames on these statistics.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import matplotlib
import numpy as np
from skimage.measure import label

from simtest.constants import LUMA_BT601
from simtest.reconstruct.detect import default_full_scale, detect_specularities, image_smooth_sigma_px
from simtest.reconstruct.images import quiet_stderr
from simtest.reconstruct.settings import ReconSettings

matplotlib.use("Agg", force=False)
import matplotlib.pyplot as plt  # noqa: E402 - after choosing the back-end

__all__ = [
    "DARK_LEVEL",
    "SATURATED_LEVEL",
    "WHITE_LEVEL",
    "FACTOR_GOAL",
    "RATIO_FLOOR",
    "STATISTICS",
    "POOLED",
    "FrameStats",
    "banner_frames",
    "log_ratio",
    "real_reference",
    "frame_stats",
    "sim_to_real_table",
    "sim_to_real_figure",
    "fit_figure",
]

#: Luma at or below which a pixel is outside the lit field (black border, field stop), 8-bit.
DARK_LEVEL = 20
#: Luma at or above this: a near-white pixel, part of a highlight candidate (8-bit; below 255
#: because JPEG rings around clipped blobs).
WHITE_LEVEL = 230
#: Luma at or above this: a saturated pixel (8-bit, JPEG margin as above).
SATURATED_LEVEL = 250
#: The sim-to-real goal: each statistic within this factor of the real frames' median.
FACTOR_GOAL = 2.0


#: The statistics of :func:`frame_stats`, in table order, with the unit each is given in.
STATISTICS = {
    "saturated_fraction": "fraction of the lit field",
    "candidates_per_mp": "near-white blobs per megapixel of lit field",
    "median_area_px": "px",
    "p90_area_px": "px",
    "tissue_r": "8-bit level",
    "tissue_g": "8-bit level",
    "tissue_b": "8-bit level",
    "colour_spread": "8-bit levels (IQR of R - G)",
    "luma_p10": "8-bit level",
    "luma_p50": "8-bit level",
    "luma_p90": "8-bit level",
    "detector_per_mp": "detector candidates per megapixel of lit field",
}

#: Floor added to both sides of a ratio in :func:`log_ratio` (the loss of the fit), per statistic:
#: about the smallest difference that matters at a real frame's scale (one blob in a 280 px tile
#: is 13 per megapixel, one pixel of area, one 8-bit level, a saturated fraction of 1e-5), so that
#: a statistic near 0 on both sides is not an infinite disagreement.
RATIO_FLOOR = {"saturated_fraction": 1e-5, "candidates_per_mp": 10.0, "median_area_px": 0.5,
               "p90_area_px": 0.5, "tissue_r": 1.0, "tissue_g": 1.0, "tissue_b": 1.0,
               "colour_spread": 1.0, "luma_p10": 1.0, "luma_p50": 1.0, "luma_p90": 1.0,
               "detector_per_mp": 10.0}


@dataclass(frozen=True)
class FrameStats:
    """Statistics of one 8-bit RGB frame (see the module docstring and :data:`STATISTICS`)."""

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

    def values(self) -> dict[str, float]:
        """The scalar statistics by name, in the order of :data:`STATISTICS` (tissue colour as
        three entries)."""
        return {"saturated_fraction": self.saturated_fraction, "candidates_per_mp": self.candidates_per_mp,
                "median_area_px": self.median_area_px, "p90_area_px": self.p90_area_px,
                "tissue_r": self.tissue_rgb[0], "tissue_g": self.tissue_rgb[1],
                "tissue_b": self.tissue_rgb[2], "colour_spread": self.colour_spread,
                "luma_p10": self.luma_p10, "luma_p50": self.luma_p50, "luma_p90": self.luma_p90,
                "detector_per_mp": self.detector_per_mp}


def _detector_count(frame: np.ndarray) -> int:
    """Bright components simtest's detector finds with the defaults for whole frames
    (:meth:`~simtest.reconstruct.settings.ReconSettings.for_frames`: local peaks, smoothing chosen
    from the noise), every component counted (no ``max_candidates`` cap)."""
    st = ReconSettings.for_frames()
    fs = default_full_scale(frame)
    det = detect_specularities(frame, brightness_rel=st.brightness_rel, full_scale=fs,
                               saturation_level=st.saturation_level, min_area_px=st.min_area_px,
                               smooth_sigma_px=image_smooth_sigma_px(frame, fs), method=st.detection,
                               peak_rel=st.peak_rel, max_candidates=None)
    return det.n_components


def frame_stats(frame: np.ndarray, *, detector: bool = True) -> FrameStats:
    """Statistics of an 8-bit RGB frame (H, W, 3), as in the module docstring.

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
    lum = f.astype(np.float64) @ LUMA_BT601
    lit = lum > DARK_LEVEL
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
    return FrameStats(
        candidates_per_mp=len(areas) / mp,
        median_area_px=float(np.median(areas)) if len(areas) else 0.0,
        p90_area_px=float(np.percentile(areas, 90)) if len(areas) else 0.0,
        saturated_fraction=float(sat.sum() / lit.sum()),
        tissue_rgb=tuple(float(x) for x in rgb),
        areas=areas,
        colour_spread=spread, luma_p10=p10, luma_p50=p50, luma_p90=p90,
        detector_per_mp=_detector_count(f) / mp if detector else float("nan"),
    )


#: Statistics of the glint population: the real frames' value is pooled over the frames (every
#: frame's blobs and lit pixels together) rather than a median of per-frame values, which on real
#: frames (many with no glint at all, a few with hundreds) swings by a factor of 30 between two
#: halves of the Hyper-Kvasir banner. The others are medians over the frames.
POOLED = ("saturated_fraction", "candidates_per_mp", "median_area_px", "p90_area_px", "detector_per_mp")


def real_reference(frames: list[np.ndarray], stats: list[FrameStats] | None = None) -> dict[str, float]:
    """The real frames' value of each statistic (:data:`STATISTICS`): pooled over the frames for
    the glint population (:data:`POOLED`: saturated pixels over lit pixels, blobs and detector
    candidates per megapixel of all the frames' lit field, the median and 90th percentile of all
    the blobs' areas), the median over the frames for the others.

    Parameters
    ----------
    frames : list of ndarray of shape (h, w, 3), uint8
    stats : list of FrameStats, optional
        Their :func:`frame_stats`, if already computed.
    """
    st = stats if stats is not None else [frame_stats(f) for f in frames]
    lit_mp = np.array([float(((np.asarray(f, np.float64) @ LUMA_BT601) > DARK_LEVEL).sum()) / 1e6 for f in frames])
    vals = [s.values() for s in st]
    out = {k: float(np.nanmedian([v[k] for v in vals])) for k in STATISTICS}
    total = lit_mp.sum()
    out["saturated_fraction"] = float(sum(s.saturated_fraction * m for s, m in zip(st, lit_mp)) / total)
    out["candidates_per_mp"] = float(sum(len(s.areas) for s in st) / total)
    out["detector_per_mp"] = float(np.nansum([s.detector_per_mp * m for s, m in zip(st, lit_mp)]) / total)
    areas = np.concatenate([s.areas for s in st]) if st else np.zeros(0)
    out["median_area_px"] = float(np.median(areas)) if len(areas) else 0.0
    out["p90_area_px"] = float(np.percentile(areas, 90)) if len(areas) else 0.0
    return out


def log_ratio(key: str, value: float, reference: float) -> float:
    """``log((value + floor) / (reference + floor))`` with the statistic's :data:`RATIO_FLOOR`."""
    fl = RATIO_FLOOR[key]
    return float(np.log((value + fl) / (reference + fl)))


def banner_frames(path: str | Path, tile_px: int = 280) -> list[np.ndarray]:
    """The frames of the Hyper-Kvasir banner: its ``tile_px`` x ``tile_px`` tiles, RGB uint8.

    Raises
    ------
    ValueError
        If the file cannot be read as an image.
    """
    with quiet_stderr():  # the decoder's own lines (libpng, libjpeg): the error names the file
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    H, W = img.shape[:2]
    return [img[r:r + tile_px, c:c + tile_px].copy() for r in range(0, H - tile_px + 1, tile_px)
            for c in range(0, W - tile_px + 1, tile_px)]


def at_height(frame: np.ndarray, height_px: int) -> np.ndarray:
    """``frame`` resized to ``height_px`` rows (aspect kept), area averaging."""
    H, W = frame.shape[:2]
    w = max(1, int(round(W * height_px / H)))
    return cv2.resize(frame, (w, height_px), interpolation=cv2.INTER_AREA)


def sim_to_real_table(rendered: np.ndarray, real: list[np.ndarray]) -> list[dict]:
    """Compare a rendered frame with real frames, statistic by statistic.

    Parameters
    ----------
    rendered : ndarray of shape (H, W, 3), uint8
        The rendered video frame (resized to the real frames' height first).
    real : list of ndarray of shape (h, w, 3), uint8
        Real frames (one height).

    Returns
    -------
    list of dict
        One row per statistic (:data:`STATISTICS`): ``statistic``, ``rendered``, ``real`` (the real
        frames' value, :func:`real_reference`: pooled for the glint population, else the median),
        ``real_pooled`` (whether it is pooled), ``real_q25``, ``real_q75`` (quartiles of the
        per-frame values), ``ratio`` (rendered / real; NaN if real is 0) and ``within_goal``
        (ratio in [1 / FACTOR_GOAL, FACTOR_GOAL]).
    """
    h = real[0].shape[0]
    sim = frame_stats(at_height(rendered, h)).values()
    real_st = [frame_stats(f) for f in real]
    ref = real_reference(real, real_st)
    reals = [s.values() for s in real_st]
    rows = []
    for key, value in sim.items():
        vals = np.array([r[key] for r in reals], dtype=np.float64)
        med = ref[key]
        ratio = value / med if med > 0 else float("nan")
        rows.append({"statistic": key, "rendered": float(value), "real": med, "real_pooled": key in POOLED,
                     "real_q25": float(np.nanpercentile(vals, 25)),
                     "real_q75": float(np.nanpercentile(vals, 75)), "ratio": ratio,
                     "within_goal": bool(np.isfinite(ratio) and 1 / FACTOR_GOAL <= ratio <= FACTOR_GOAL)})
    return rows


def sim_to_real_figure(rendered: np.ndarray, real: list[np.ndarray], rows: list[dict]):
    """Figure: the rendered frame, six real frames, the candidates' area distributions and the
    ratio of each statistic (the factor-2 band shaded). Returns a matplotlib Figure."""
    h = real[0].shape[0]
    sim_frame = at_height(rendered, h)
    fig = plt.figure(figsize=(12, 7.5), constrained_layout=True)
    gs = fig.add_gridspec(3, 5)
    ax = fig.add_subplot(gs[0:2, 0:2])
    ax.imshow(sim_frame)
    ax.set_title(f"rendered ({rendered.shape[1]} x {rendered.shape[0]} px, shown at {h} px high)")
    ax.axis("off")
    for i, f in enumerate(real[:6]):
        a = fig.add_subplot(gs[i // 3, 2 + i % 3])
        a.imshow(f)
        a.set_title(f"real frame {i}", fontsize=9)
        a.axis("off")
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


def fit_figure(before: np.ndarray, after: np.ndarray, fitted: list[np.ndarray], held: list[np.ndarray],
               tables: dict):
    """Figure of a fit (``simtest simreal --fit``): the rendered frame before and after beside
    real frames (two fitted, two held out), and each statistic's ratio (rendered / real) before
    and after on the fitted and the held-out frames, the factor-2 band shaded.

    ``tables``: ``{"fitted": {"before": rows, "after": rows}, "held_out": {...}}`` of
    :func:`sim_to_real_table`. Returns a matplotlib Figure.
    """
    h = fitted[0].shape[0]
    fig = plt.figure(figsize=(13, 8), constrained_layout=True)
    gs = fig.add_gridspec(2, 6)
    shown = [(at_height(before, h), "rendered, before the fit"), (at_height(after, h), "rendered, after the fit")]
    shown += [(f, f"fitted real frame {i}") for i, f in enumerate(fitted[:2])]
    shown += [(f, f"held-out real frame {i}") for i, f in enumerate(held[:2])]
    for i, (f, title) in enumerate(shown):
        a = fig.add_subplot(gs[0, i])
        a.imshow(f)
        a.set_title(title, fontsize=9)
        a.axis("off")
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
