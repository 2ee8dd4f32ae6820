"""Outside-style sensor frames with Phong lobes, written with their camera file and reconstructed as a
user does: a second generator beside ``test_rig_pairs.sensor_plane`` (Blinn lobes), of other physics
(the mirror direction's lobe, no cosine in it) so that the tests do not fit one generator only."""

from __future__ import annotations

import json

import numpy as np
from PIL import Image
from typer.testing import CliRunner

from simtest.cli import app


def _srgb(s):
    return np.where(s <= 0.0031308, 12.92 * s, 1.055 * np.power(np.maximum(s, 0.0031308), 1 / 2.4) - 0.055)


def phong_frame(W, H, f, guides, normal, depth_mm, phong_n, ks, tissue, median, noise, seed, white=None):
    """An 8-bit sRGB frame of a plane: per guide, Lambertian shading ``cos / r^2`` in the tissue's colour and a
    white Phong lobe ``ks (R . V)^n / r^2`` (mirror direction R), exposed so that the shading's median is
    ``median`` of full scale in the tissue's brightest channel, ``white`` (H, W) added in every channel (linear
    light, full scale 1), Gaussian noise before the curve, clipped.
    Returns the frame, K and each guide's specular point (u, v) px."""
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1.0]])
    h = depth_mm * -normal[2]
    vv, uu = np.mgrid[0:H, 0:W].astype(float)
    d = np.stack([(uu - K[0, 2]) / f, (vv - K[1, 2]) / f, np.ones_like(uu)], -1)
    X = d * (-h / (d @ normal))[..., None]
    V = -X / np.linalg.norm(X, axis=-1, keepdims=True)
    shade, lobes, truth = 0.0, 0.0, []
    for L in guides:
        Ld = L - X
        r = np.linalg.norm(Ld, axis=-1)
        Ld /= r[..., None]
        cos = Ld @ normal
        R = 2 * cos[..., None] * normal - Ld
        shade = shade + np.maximum(cos, 0) / r ** 2
        lobes = lobes + (cos > 0) * np.maximum((R * V).sum(-1), 0) ** phong_n / r ** 2
        Lm = L - 2 * (normal @ L + h) * normal  # the guide's mirror image: the specular point on its ray
        Xs = Lm * (h / -(normal @ Lm))
        truth.append((K @ Xs)[:2] / Xs[2])
    rgb = median / np.median(shade * max(tissue)) * (shade[..., None] * np.asarray(tissue) + ks * lobes[..., None])
    rgb = rgb if white is None else rgb + np.asarray(white)[..., None]
    s = np.clip(rgb + np.random.default_rng(seed).normal(0, noise, rgb.shape), 0, 1)
    return np.rint(_srgb(s) * 255).astype(np.uint8), K, truth


def reconstruct_frame(folder, img, K, guides) -> list[dict]:
    """``img`` written to ``folder`` with its camera file (sRGB, the ``guides`` (k, 3) mm with the inverse
    square), ``simtest reconstruct`` run on it in one process; its estimates' ``specularities``."""
    Image.fromarray(img).save(folder / "frame.png", compress_level=1)  # (lossless: zlib level 1 is fastest)
    cam = {"model": "pinhole", "K": K.tolist(), "image_size": [img.shape[1], img.shape[0]],
           "response": {"curve": "srgb", "white_balance": [1, 1, 1], "exposure": 1.0, "clip": 255.0},
           "lights": [{"position_mm": L.tolist(), "intensity": 1.0, "falloff": "inverse_square",
                       "profile_exponent": 0.0} for L in guides]}
    (folder / "camera.json").write_text(json.dumps(cam))
    res = CliRunner().invoke(app, ["reconstruct", str(folder / "frame.png"), "--intrinsics", str(folder / "camera.json"),
                                   "-o", str(folder / "out"), "--no-overlay", "--workers", "1"])
    assert res.exit_code == 0, res.output
    return json.loads((folder / "out" / "estimates.json").read_text())["specularities"]


def nearest_row(specs: list[dict], uv) -> tuple[float, dict]:
    """The distance (px) from ``uv`` to the nearest estimate's BP, and that estimate."""
    d = [float(np.hypot(*(np.asarray(s["bp_px"]) - uv))) for s in specs]
    return min(d), specs[int(np.argmin(d))]
