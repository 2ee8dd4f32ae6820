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
- **tissue colour**: the median R, G, B of the lit field outside the highlights.

Frames of different resolutions are compared at the real frames' scale: the rendered frame is
resized (area averaging, OpenCV's INTER_AREA) to the real frames' height first. The real frames
bundled with the project are the 24 frames of the Hyper-Kvasir banner (``tests/data/real``, CC BY
4.0, Borgli et al., Scientific Data 7, 283, 2020, https://doi.org/10.1038/s41597-020-00622-y):
280 x 280 px each, JPEG, some with burnt-in text or green boxes (which the near-white and colour
statistics partly see).

The goal is a factor 2 on each statistic between the rendered frame and the median real frame
(:func:`sim_to_real_table`); :func:`sim_to_real_figure` shows the frames and the area
distributions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import matplotlib
import numpy as np
from skimage.measure import label

from simtest.constants import LUMA_BT601

matplotlib.use("Agg", force=False)
import matplotlib.pyplot as plt  # noqa: E402 - after choosing the back-end

__all__ = [
    "DARK_LEVEL",
    "SATURATED_LEVEL",
    "WHITE_LEVEL",
    "FACTOR_GOAL",
    "FrameStats",
    "banner_frames",
    "frame_stats",
    "sim_to_real_table",
    "sim_to_real_figure",
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


@dataclass(frozen=True)
class FrameStats:
    """Statistics of one 8-bit RGB frame (see the module docstring)."""

    candidates_per_mp: float
    median_area_px: float
    p90_area_px: float
    saturated_fraction: float
    tissue_rgb: tuple[float, float, float]
    areas: np.ndarray  # (n,) pixel areas of the candidates

    def values(self) -> dict[str, float]:
        """The scalar statistics by name (tissue colour as three entries)."""
        return {"candidates_per_mp": self.candidates_per_mp, "median_area_px": self.median_area_px,
                "p90_area_px": self.p90_area_px, "saturated_fraction": self.saturated_fraction,
                "tissue_r": self.tissue_rgb[0], "tissue_g": self.tissue_rgb[1],
                "tissue_b": self.tissue_rgb[2]}


def frame_stats(frame: np.ndarray) -> FrameStats:
    """Statistics of an 8-bit RGB frame (H, W, 3), as in the module docstring.

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
    rgb = np.median(f[tissue], axis=0) if tissue.any() else np.full(3, np.nan)
    return FrameStats(
        candidates_per_mp=len(areas) / mp,
        median_area_px=float(np.median(areas)) if len(areas) else 0.0,
        p90_area_px=float(np.percentile(areas, 90)) if len(areas) else 0.0,
        saturated_fraction=float(sat.sum() / lit.sum()),
        tissue_rgb=tuple(float(x) for x in rgb),
        areas=areas,
    )


def banner_frames(path: str | Path, tile_px: int = 280) -> list[np.ndarray]:
    """The frames of the Hyper-Kvasir banner: its ``tile_px`` x ``tile_px`` tiles, RGB uint8.

    Raises
    ------
    ValueError
        If the file cannot be read as an image.
    """
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
        One row per statistic: ``statistic``, ``rendered``, ``real_median``, ``real_q25``,
        ``real_q75``, ``ratio`` (rendered / real median; NaN if the median is 0) and
        ``within_goal`` (ratio in [1 / FACTOR_GOAL, FACTOR_GOAL]).
    """
    h = real[0].shape[0]
    sim = frame_stats(at_height(rendered, h)).values()
    reals = [frame_stats(f).values() for f in real]
    rows = []
    for key, value in sim.items():
        vals = np.array([r[key] for r in reals], dtype=np.float64)
        med = float(np.nanmedian(vals))
        ratio = value / med if med > 0 else float("nan")
        rows.append({"statistic": key, "rendered": float(value), "real_median": med,
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
    b.set_ylabel("rendered / real median")
    b.legend(fontsize=8)
    return fig
