"""Sensor model: exposure, shot and read noise, saturation, gamma and quantisation (numpy only).

:func:`apply_sensor` makes the grey sensor image of the paper's protocol; :func:`video_frame` the
8-bit RGB frame of a scope's video camera (auto-exposure, white balance, tone curve, colour
saturation, vignetting, field stop, JPEG).
"""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

from simtest.constants import LUMA_BT601
from simtest.scene.spec import SensorSpec

__all__ = ["LUMA_WEIGHTS", "SENSOR_SEED_KEY", "apply_sensor", "field_stop_mask", "frame_luma",
           "sensor_dtype", "video_frame"]

#: Stable key of the sensor-noise stream in ``SeedSequence([seed, SENSOR_SEED_KEY])``.
SENSOR_SEED_KEY = 0x5E750


def sensor_dtype(bit_depth: int) -> type:
    """``np.uint8`` for bit depths up to 8, else ``np.uint16``."""
    return np.uint8 if bit_depth <= 8 else np.uint16


def apply_sensor(linear: np.ndarray, sensor: SensorSpec, seed: int) -> np.ndarray:
    """Turn a linear radiance image into a quantised sensor image.

    Steps, in order: ``s = exposure * linear`` (full scale is s = 1); shot noise
    ``s = Poisson(s * full_well_e) / full_well_e`` if ``full_well_e > 0``; read noise
    ``s += N(0, gaussian_sigma^2)``; clip to ``[0, saturation]``; gamma ``s^(1 / gamma)``;
    quantise ``round(s * (2^bit_depth - 1))``.

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
    levels = (1 << sensor.bit_depth) - 1
    return np.rint(s * levels).astype(sensor_dtype(sensor.bit_depth))


#: Luma weights of ITU-R BT.601 (the video luma of an RGB frame): :data:`simtest.constants.LUMA_BT601`.
LUMA_WEIGHTS = LUMA_BT601


def field_stop_mask(shape: tuple[int, int], kind: str, radius: float) -> np.ndarray:
    """Pixels inside a scope's field stop, centred on the image.

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
    H, W = shape
    if kind == "none":
        return np.ones((H, W), dtype=bool)
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    x, y = x - (W - 1) / 2.0, y - (H - 1) / 2.0
    R = radius * W / 2.0
    if kind == "circle":
        return x * x + y * y <= R * R
    ax, ay = np.abs(x), np.abs(y)
    return (ax <= R) & (ay <= R) & ((ax + ay) / np.sqrt(2.0) <= R)


def _srgb(s: np.ndarray) -> np.ndarray:
    return np.where(s <= 0.0031308, 12.92 * s, 1.055 * np.power(np.maximum(s, 0.0031308), 1 / 2.4) - 0.055)


def video_frame(rgb: np.ndarray, sensor: SensorSpec, seed: int) -> np.ndarray:
    """An 8-bit RGB video frame from a linear RGB image, as a scope's camera makes it.

    Steps, in order: exposure (``exposure``, or "auto": the mean luma inside the field stop made
    ``auto_mean``); vignetting ``1 - v (r / r_max)^2``; white-balance gains; shot noise (Poisson,
    ``full_well_e`` electrons at full scale) and read noise (``gaussian_sigma``), per channel;
    clipping at ``saturation`` (then scaled to full scale); colour saturation about the BT.601
    luma; the tone curve (``gamma`` or sRGB); 8-bit quantisation; the field stop (black outside);
    JPEG at ``jpeg_quality`` (encoded and decoded with Pillow, 4:2:0 chroma) when > 0.

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3) or (H, W)
        Linear radiance (a grey image is used for all three channels).
    sensor : SensorSpec
    seed : int
        Root seed; the noise stream is ``SeedSequence([seed, SENSOR_SEED_KEY, 1])`` (the grey
        sensor image's stream is ``[seed, SENSOR_SEED_KEY]``).

    Returns
    -------
    ndarray of shape (H, W, 3), uint8
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, axis=-1)
    rgb = np.maximum(rgb, 0.0)
    H, W = rgb.shape[:2]
    stop = field_stop_mask((H, W), sensor.field_stop, sensor.field_stop_radius)
    luma_w = np.asarray(LUMA_WEIGHTS)
    if sensor.exposure_mode == "auto":
        mean = float(np.mean((rgb @ luma_w)[stop])) if stop.any() else 0.0
        exposure = sensor.auto_mean * sensor.saturation / mean if mean > 0 else 1.0
    else:
        exposure = sensor.exposure
    s = rgb * exposure
    if sensor.vignetting > 0:
        y, x = np.mgrid[0:H, 0:W].astype(np.float64)
        r2 = ((x - (W - 1) / 2) ** 2 + (y - (H - 1) / 2) ** 2) / (((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2)
        s *= (1.0 - sensor.vignetting * r2)[..., None]
    s *= np.asarray(sensor.white_balance)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), SENSOR_SEED_KEY, 1]))
    if sensor.full_well_e > 0:
        s = rng.poisson(s * sensor.full_well_e) / sensor.full_well_e
    if sensor.gaussian_sigma > 0:
        s = s + rng.normal(0.0, sensor.gaussian_sigma, size=s.shape)
    s = np.clip(s, 0.0, sensor.saturation) / sensor.saturation
    if sensor.color_saturation != 1.0:
        y = (s @ luma_w)[..., None]
        s = np.clip(y + sensor.color_saturation * (s - y), 0.0, 1.0)
    s = _srgb(s) if sensor.tone == "srgb" else s ** (1.0 / sensor.gamma)
    frame = np.rint(s * 255.0).astype(np.uint8)
    frame[~stop] = 0
    if sensor.jpeg_quality > 0:
        buf = io.BytesIO()
        Image.fromarray(frame, mode="RGB").save(buf, format="JPEG", quality=int(sensor.jpeg_quality))
        buf.seek(0)
        frame = np.asarray(Image.open(buf).convert("RGB"), dtype=np.uint8).copy()
    return frame


def frame_luma(frame: np.ndarray) -> np.ndarray:
    """BT.601 luma of an 8-bit RGB frame, rounded to uint8 (H, W)."""
    return np.rint(np.asarray(frame, dtype=np.float64) @ np.asarray(LUMA_WEIGHTS)).clip(0, 255).astype(np.uint8)
