"""``simtest dataset show DIR``: a contact sheet to look at a dataset at a glance.

One row per sample: the sensor image with the ground-truth BPs (red crosses) and isophote ellipses
(cyan), the normals as colours, and the surface mask with the highlight mask over it.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Ellipse

from simtest._io import atomic_write
from simtest.dataset.reader import SimtestDataset

__all__ = ["contact_sheet"]


def contact_sheet(root, out=None, count: int = 8, start: int = 0) -> Path:
    """Write a contact sheet PNG of ``count`` samples of a dataset.

    Parameters
    ----------
    root : path
        A complete dataset folder.
    out : path, optional
        PNG file to write (default ``<root>/contact_sheet.png``), replaced atomically.
    count : int
        Samples shown (one row each), from position ``start`` on.
    start : int
        First sample shown.

    Returns
    -------
    Path
        The PNG written.

    Raises
    ------
    DatasetError
        If ``root`` is not a complete dataset.
    ValueError
        If ``count < 1`` or ``start`` is outside the dataset.
    """
    ds = SimtestDataset(root, keys=("sensor", "normals", "mask", "highlight_mask"))
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    if len(ds) and not 0 <= start < len(ds):
        raise ValueError(f"start {start} is outside 0..{len(ds) - 1}")
    picks = list(range(start, min(len(ds), start + count)))
    out = Path(out) if out is not None else Path(root) / "contact_sheet.png"
    rows = max(1, len(picks))
    fig, axes = plt.subplots(rows, 3, figsize=(9, 3.1 * rows), squeeze=False)
    for r, k in enumerate(picks):
        s = ds[k]
        rec = s["record"]
        img = s["sensor"]
        ax = axes[r, 0]
        ax.imshow(img, cmap="gray" if img.ndim == 2 else None, vmin=0, vmax=255)
        h, w = img.shape[:2]
        for hl in rec.get("highlights", []):
            u, v = hl["bp_px"]
            if 0 <= u < w and 0 <= v < h:
                ax.plot([u], [v], "+", color="red", ms=10, mew=1.5)
            for iso in hl.get("isophotes", []):
                e = iso.get("ellipse")
                if e:
                    ax.add_patch(Ellipse(e["center_px"], 2 * e["semi_axes_px"][0], 2 * e["semi_axes_px"][1],
                                         angle=e["angle_deg"], fill=False, color="cyan", lw=0.8))
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
        ax.set_title(f"#{rec['index']} {rec['family']} ({rec.get('split', '-')}), "
                     f"exposure x{rec.get('exposure_applied', 1.0):.3g}", fontsize=8)
        n = s["normals"]  # (x, y, -z) from [-1, 1] to [0, 1]; black off the mask
        rgb = (np.stack([n[..., 0], n[..., 1], -n[..., 2]], -1) + 1.0) / 2.0
        axes[r, 1].imshow(np.where(s["mask"][..., None], np.clip(rgb, 0, 1), 0.0))
        axes[r, 1].set_title("normals (camera frame; RGB = x, y, -z)", fontsize=8)
        overlay = np.zeros((*s["mask"].shape, 3))
        overlay[s["mask"]] = (0.35, 0.35, 0.35)
        overlay[s["highlight_mask"]] = (1.0, 0.85, 0.1)
        axes[r, 2].imshow(overlay)
        axes[r, 2].set_title("mask (grey), highlight mask (yellow)", fontsize=8)
        for ax in axes[r]:
            ax.set_xlabel("u (px)", fontsize=7)
            ax.set_ylabel("v (px)", fontsize=7)
            ax.tick_params(labelsize=6)
    if not picks:
        axes[0, 0].set_title("empty dataset")
    fig.suptitle(f"{Path(root).name}: samples {picks[0] if picks else '-'}..{picks[-1] if picks else '-'} "
                 f"of {len(ds)}; red +: brightest point (BP), cyan: isophote ellipses", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.4 / (3.1 * rows)))  # 0.4 inch for the title
    atomic_write(out, lambda tmp: fig.savefig(tmp, dpi=90, format="png"), suffix=".png")
    plt.close(fig)
    ds.close()
    return out
