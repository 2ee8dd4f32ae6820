"""Sensor model: exposure, shot and read noise, saturation, gamma and quantisation (numpy only).

:func:`apply_sensor` makes the grey sensor image of the paper's protocol; :func:`video_frame` the
8-bit RGB frame of a scope's video camera (auto-exposure, white balance, tone curve, colour
saturation, vignetting, field stop, JPEG).
"""

from __future__ import annotations

import functools
import io
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from PIL import Image

from simtest.constants import LUMA_BT601
from simtest.geometry.response import srgb_encode
from simtest.scene.spec import SensorSpec

__all__ = ["LUMA_WEIGHTS", "SENSOR_SEED_KEY", "VIDEO_BANDS", "apply_sensor", "field_stop_mask", "frame_luma",
           "peak_exposure", "sensor_dtype", "video_frame"]

#: Stable key of the sensor-noise stream in ``SeedSequence([seed, SENSOR_SEED_KEY])``.
SENSOR_SEED_KEY = 0x5E750


def sensor_dtype(bit_depth: int) -> type:
    """``np.uint8`` for bit depths up to 8, else ``np.uint16``."""
    return np.uint8 if bit_depth <= 8 else np.uint16


def apply_sensor(linear: np.ndarray, sensor: SensorSpec, seed: int) -> np.ndarray:
    """Turn a linear radiance image into a quantised sensor image.

    In order: ``s = exposure * linear``; shot noise ``Poisson(s * full_well_e) / full_well_e`` if
    ``full_well_e > 0``; read noise ``N(0, gaussian_sigma^2)``; clip to ``[0, saturation]``; ``s^(1 / gamma)``;
    ``round(s * (2^bit_depth - 1))``.

    Parameters
    ----------
    linear : ndarray of shape (H, W) or (H, W, C)
        Linear radiance, >= 0.
    sensor : SensorSpec
    seed : int
        Root seed; the noise stream is ``SeedSequence([seed, SENSOR_SEED_KEY])``.

    Returns
    -------
    ndarray of shape like ``linear``, dtype uint8 (bit_depth <= 8) or uint16
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), SENSOR_SEED_KEY]))
    s = np.maximum(np.asarray(linear, dtype=np.float64), 0.0) * sensor.exposure
    if sensor.full_well_e > 0:
        s = rng.poisson(s * sensor.full_well_e) / sensor.full_well_e
    if sensor.gaussian_sigma > 0:
        s = s + rng.normal(0.0, sensor.gaussian_sigma, size=s.shape)
    s = np.clip(s, 0.0, sensor.saturation)
    if sensor.gamma != 1.0:
        s = s ** (1.0 / sensor.gamma)
    return np.rint(s * ((1 << sensor.bit_depth) - 1)).astype(sensor_dtype(sensor.bit_depth))


#: Luma weights of ITU-R BT.601 (the video luma of an RGB frame): :data:`simtest.constants.LUMA_BT601`.
LUMA_WEIGHTS = LUMA_BT601


def field_stop_mask(shape: tuple[int, int], kind: str, radius: float) -> np.ndarray:
    """Pixels inside a scope's field stop, centred on the image (a read-only array, cached).

    Parameters
    ----------
    shape : (H, W)
    kind : {"none", "circle", "octagon"}
        "octagon": the regular octagon whose inscribed circle is the circle (Olympus frames).
    radius : float
        Radius as a fraction of half the image width.

    Returns
    -------
    ndarray of shape (H, W), bool
    """
    return _field_stop((int(shape[0]), int(shape[1])), str(kind), float(radius))


@functools.lru_cache(maxsize=8)
def _field_stop(shape: tuple[int, int], kind: str, radius: float) -> np.ndarray:
    H, W = shape
    if kind == "none":
        out = np.ones((H, W), dtype=bool)
    else:
        y, x = np.mgrid[0:H, 0:W].astype(np.float64)
        x, y = x - (W - 1) / 2.0, y - (H - 1) / 2.0
        R = radius * W / 2.0
        if kind == "circle":
            out = x * x + y * y <= R * R
        else:
            ax, ay = np.abs(x), np.abs(y)
            out = (ax <= R) & (ay <= R) & ((ax + ay) / np.sqrt(2.0) <= R)
    out.flags.writeable = False
    return out


#: Row bands of a video frame, each with its own noise stream (:func:`video_frame`)
VIDEO_BANDS = 16


@functools.lru_cache(maxsize=8)
def _vignetting_gain(shape: tuple[int, int], vignetting: float) -> np.ndarray:
    """``1 - v (r / r_max)^2`` per pixel, r from the image centre, r_max its corner (read-only)."""
    H, W = shape
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    r2 = ((x - (W - 1) / 2) ** 2 + (y - (H - 1) / 2) ** 2) / (((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2)
    gain = 1.0 - vignetting * r2
    gain.flags.writeable = False
    return gain


def peak_exposure(rgb: np.ndarray, meter: np.ndarray, sensor: SensorSpec) -> float:
    """The largest exposure at which at most ``sensor.auto_clip_percent`` % of the metered pixels
    clip in their brightest white-balanced channel (before noise and vignetting).

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3) or (H, W, 1)
        Linear radiance.
    meter : ndarray of shape (H, W), bool
        The metered pixels (at least one).
    sensor : SensorSpec

    Returns
    -------
    float
        The exposure (``inf`` where the metered pixels' quantile is 0: nothing would clip).
    """
    peak = (np.maximum(rgb[meter], 0.0) * np.asarray(sensor.white_balance)).max(axis=-1)
    q = float(np.quantile(peak, 1.0 - sensor.auto_clip_percent / 100.0))
    return sensor.saturation / q if q > 0 else float("inf")


def video_frame(rgb: np.ndarray, sensor: SensorSpec, seed: int, *, threads: int | None = None,
                tissue: np.ndarray | None = None) -> np.ndarray:
    """An 8-bit RGB video frame from a linear RGB image, as a scope's camera makes it.

    Steps, in order: exposure (``exposure``, or "auto": the mean luma inside the field stop, or
    of its pixels on tissue with ``metering = "tissue"``, made ``auto_mean``, but no more than
    lets ``auto_clip_percent`` % of them clip: :func:`peak_exposure`); vignetting ``1 - v (r / r_max)^2``; white-balance gains; shot noise (Poisson,
    ``full_well_e`` electrons at full scale) and read noise (``gaussian_sigma``), per channel;
    clipping at ``saturation`` (then scaled to full scale); colour saturation about the BT.601
    luma; the tone curve (``gamma`` or sRGB); 8-bit quantisation; the field stop (black outside);
    JPEG at ``jpeg_quality`` (encoded and decoded with Pillow, 4:2:0 chroma) when > 0.

    Every step but the auto-exposure (a mean over the frame) is per pixel; they run on
    :data:`VIDEO_BANDS` row bands, on ``threads`` threads (numpy releases the GIL), each band with
    its own noise stream, so the frame does not depend on ``threads``.

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3) or (H, W)
        Linear radiance (a grey image is used for all three channels).
    sensor : SensorSpec
    seed : int
        Root seed; band b's noise stream is ``SeedSequence([seed, SENSOR_SEED_KEY, 1, b])`` (the
        grey sensor image's stream is ``[seed, SENSOR_SEED_KEY]``).
    threads : int, optional
        Threads that develop the bands (default: the CPU count, at most 4).
    tissue : ndarray of shape (H, W), bool, optional
        Pixels on tissue: with ``sensor.metering = "tissue"`` the auto-exposure averages the
        field stop's pixels among them only (all of the field stop without it).

    Returns
    -------
    ndarray of shape (H, W, 3), uint8
    """
    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        rgb = rgb[..., None]  # broadcast over the three channels below
    H, W = rgb.shape[:2]
    stop = field_stop_mask((H, W), sensor.field_stop, sensor.field_stop_radius)
    luma_w = np.asarray(LUMA_WEIGHTS)
    if sensor.exposure_mode == "auto":
        luma = np.maximum(rgb, 0.0) @ luma_w if rgb.shape[-1] == 3 else np.maximum(rgb[..., 0], 0.0) * luma_w.sum()
        meter = stop
        if sensor.metering == "tissue" and tissue is not None and (stop & tissue).any():
            meter = stop & np.asarray(tissue, dtype=bool)
        mean = float(np.mean(luma[meter], dtype=np.float64)) if meter.any() else 0.0
        exposure = sensor.auto_mean * sensor.saturation / mean if mean > 0 else 1.0
        if sensor.auto_clip_percent < 100.0 and meter.any():
            exposure = min(exposure, peak_exposure(rgb, meter, sensor))
    else:
        exposure = sensor.exposure
    gain = _vignetting_gain((H, W), float(sensor.vignetting)) if sensor.vignetting > 0 else None
    frame = np.empty((H, W, 3), dtype=np.uint8)
    edges = np.linspace(0, H, min(VIDEO_BANDS, H) + 1).astype(int)

    def develop(b: int) -> None:
        r0, r1 = edges[b], edges[b + 1]
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), SENSOR_SEED_KEY, 1, b]))
        s = np.maximum(np.asarray(rgb[r0:r1], dtype=np.float64), 0.0) * exposure
        if s.shape[-1] == 1:
            s = np.repeat(s, 3, axis=-1)
        if gain is not None:
            s *= gain[r0:r1, :, None]
        s *= np.asarray(sensor.white_balance)
        if sensor.full_well_e > 0:
            s = rng.poisson(s * sensor.full_well_e) / sensor.full_well_e
        if sensor.gaussian_sigma > 0:
            s += rng.normal(0.0, sensor.gaussian_sigma, size=s.shape)
        s = np.clip(s, 0.0, sensor.saturation) / sensor.saturation
        if sensor.color_saturation != 1.0:
            y = (s @ luma_w)[..., None]
            s = np.clip(y + sensor.color_saturation * (s - y), 0.0, 1.0)
        # sRGB in float32: its error is far below the 8-bit step
        s = srgb_encode(s.astype(np.float32)) if sensor.tone == "srgb" else s ** (1.0 / sensor.gamma)
        band = np.rint(s * 255.0).astype(np.uint8)
        band[~stop[r0:r1]] = 0
        frame[r0:r1] = band

    n_threads = threads if threads is not None else min(4, os.cpu_count() or 1)
    if n_threads > 1 and len(edges) > 2:
        with ThreadPoolExecutor(max_workers=n_threads) as pool:
            list(pool.map(develop, range(len(edges) - 1)))
    else:
        for b in range(len(edges) - 1):
            develop(b)
    if sensor.jpeg_quality > 0:
        buf = io.BytesIO()
        Image.fromarray(frame, mode="RGB").save(buf, format="JPEG", quality=int(sensor.jpeg_quality))
        buf.seek(0)
        frame = np.asarray(Image.open(buf).convert("RGB"), dtype=np.uint8).copy()
    return frame


def frame_luma(frame: np.ndarray) -> np.ndarray:
    """BT.601 luma of an 8-bit RGB frame, rounded to uint8 (H, W)."""
    return np.rint(np.asarray(frame, dtype=np.float64) @ np.asarray(LUMA_WEIGHTS)).clip(0, 255).astype(np.uint8)
