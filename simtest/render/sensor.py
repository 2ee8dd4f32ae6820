"""Sensor model: exposure, shot and read noise, saturation, gamma and quantisation (numpy only)."""

from __future__ import annotations

import numpy as np

from simtest.scene.spec import SensorSpec

__all__ = ["SENSOR_SEED_KEY", "apply_sensor", "sensor_dtype"]

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
