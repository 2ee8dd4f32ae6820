"""The sensor's response: how a scope's camera turns linear radiance into pixel values, and back.

A camera file's optional ``"response"`` object (:mod:`simtest.geometry.camera_file`)::

    "response": {"curve": "srgb", "white_balance": [1, 1, 1], "exposure": 1.0, "clip": 255}

``"curve"`` is ``"linear"``, ``"srgb"`` (IEC 61966-2-1) or ``"gamma"`` (``s^(1 / g)`` with ``"gamma"``: g);
``"clip"`` defaults to the dtype's maximum (1 for floats). The forward model is
``pixel = clip(curve(exposure * white_balance * radiance))``; :meth:`SensorResponse.linearize` inverts it,
per channel, up to the exposure. No ``"response"`` means linear.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CURVES", "MAX_ABOVE_CLIP_SHARE", "MIN_FLOAT_PEAK_OF_CLIP", "RANGES", "ResponseError",
           "SensorResponse", "video_response"]

#: The tone curves a response may name.
CURVES = ("linear", "srgb", "gamma")
_KEYS = ("curve", "gamma", "white_balance", "exposure", "clip")
#: The largest share of a frame's values above its clip level that :meth:`SensorResponse.check_frame`
#: accepts: far above a decoder's overshoot (a few percent), far below a clip in the wrong units (nearly all).
MAX_ABOVE_CLIP_SHARE = 0.25
#: A float frame's brightest pixel must be above this fraction of a given ``"clip"`` (one 8-bit step):
#: below it the frame is in other units (a frame scaled to [0, 1] read with ``"clip": 255``).
MIN_FLOAT_PEAK_OF_CLIP = 1.0 / 255.0

#: The physical range of each number of a ``"response"`` object: key -> (least, most, unit, reason).
RANGES: dict[str, tuple[float, float, str, str]] = {
    "gamma": (0.1, 10.0, "exponent g of s^(1/g)",
              "cameras' and video standards' tone curves lie within 1 to 3 (sRGB 2.2, BT.709 1/0.45, "
              "DCI 2.6); beyond 10 the 8-bit code 1 stands for 1e-24 of full scale, past any sensor's "
              "dynamic range (1e-6 at 120 dB)"),
    "white_balance": (0.01, 100.0, "gain per channel",
                      "white-balance gains lie within 0.3 to 4 (daylight to tungsten); a factor of 100 "
                      "is a unit slip"),
    "exposure": (1e-6, 1e6, "relative linear scale",
                 "shutter times of 1 us to 1 s and gains of 1 to 64 span 1e-6 to 64 in any unit; the "
                 "fits' gain absorbs the scale, and beyond 1e6 either way the linear values leave "
                 "float32's normal range (1e-38 to 3e38) after a few products"),
    "clip": (1e-6, 2.0**32, "the file's pixel units",
             "the largest integer code a sensor writes is 2^32 - 1 (32-bit); a float frame's full "
             "scale below 1e-6 is under float32's step at 1"),
}


class ResponseError(ValueError):
    """A ``"response"`` object is unusable; the one-line message names the key."""


def srgb_inverse(v: np.ndarray) -> np.ndarray:
    """The inverse sRGB transfer curve (IEC 61966-2-1) of ``v`` in [0, 1]."""
    return np.where(v <= 0.04045, v / 12.92, ((np.maximum(v, 0.04045) + 0.055) / 1.055) ** 2.4)


def srgb_encode(s: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) of linear ``s`` in [0, 1], in ``s``'s float type."""
    s = np.asarray(s)
    c = s.dtype.type if s.dtype.kind == "f" else np.float64
    return np.where(s <= c(0.0031308), c(12.92) * s,
                    c(1.055) * np.power(np.maximum(s, c(0.0031308)), c(1 / 2.4)) - c(0.055))


@dataclass(frozen=True)
class SensorResponse:
    """A sensor's tone curve, white balance, exposure and clip level (module docstring).

    Attributes
    ----------
    curve : str
        One of :data:`CURVES`.
    gamma : float
        The exponent g of the ``"gamma"`` curve (1 otherwise).
    white_balance : tuple of 3 float
        Per-channel multipliers before the curve (> 0).
    exposure : float
        Linear scale before the curve (> 0).
    clip : float or None
        Full scale in the file's units; None: the dtype's maximum (1 for float images).
    """

    curve: str = "linear"
    gamma: float = 1.0
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    exposure: float = 1.0
    clip: float | None = None

    @classmethod
    def from_json(cls, value, where: str = "response") -> SensorResponse:
        """The response of a camera file's ``"response"`` object.

        Raises
        ------
        ResponseError
            An unknown key or curve, ``"gamma"`` given without the gamma curve or missing with it, or a number
            that is boolean, not finite, not positive or outside :data:`RANGES`; one line naming ``where`` and the key.
        """
        if not isinstance(value, dict):
            raise ResponseError(f"{where}: must be an object with a 'curve', got {value!r}")
        unknown = sorted(set(value) - set(_KEYS))
        if unknown:
            raise ResponseError(f"{where}: unknown key '{unknown[0]}' (allowed: {', '.join(_KEYS)})")
        curve = value.get("curve", "linear")
        if curve not in CURVES:
            raise ResponseError(f"{where}.curve: must be one of {', '.join(CURVES)}, got {curve!r}")
        if (curve == "gamma") != ("gamma" in value):
            raise ResponseError(f"{where}.gamma: give it with curve 'gamma' and only then")

        def number(key, default):
            return _number(value.get(key, default), key, f"{where}.{key}")

        wb = value.get("white_balance", [1.0, 1.0, 1.0])
        if not (isinstance(wb, list) and len(wb) == 3):
            raise ResponseError(f"{where}.white_balance: must be a list of 3 numbers, got {wb!r}")
        wbs = tuple(_number(v, "white_balance", f"{where}.white_balance") for v in wb)
        clip = value.get("clip")
        return cls(curve, number("gamma", 1.0) if curve == "gamma" else 1.0, wbs,
                   number("exposure", 1.0), None if clip is None else number("clip", clip))

    def to_json(self) -> dict:
        """The camera file's ``"response"`` object."""
        d = {"curve": self.curve, "white_balance": list(self.white_balance), "exposure": self.exposure}
        if self.curve == "gamma":
            d["gamma"] = self.gamma
        if self.clip is not None:
            d["clip"] = self.clip
        return d

    def full_scale(self, image) -> float:
        """The clip level of ``image`` in its units: ``clip``, else the dtype's maximum (1 for floats)."""
        if self.clip is not None:
            return float(self.clip)
        dt = np.asarray(image).dtype
        return float(np.iinfo(dt).max) if dt.kind in "ui" else 1.0

    def check_frame(self, image) -> None:
        """Refuse a frame that no sensor with this response could have written.

        Refused: an integer dtype whose maximum is below ``clip``; a float frame whose largest value is at most
        :data:`MIN_FLOAT_PEAK_OF_CLIP` of a given ``clip``; more than :data:`MAX_ABOVE_CLIP_SHARE` of the values
        above ``clip`` (a decoder's overshoot leaves only a few there).

        Parameters
        ----------
        image : ndarray of shape (H, W) or (H, W, 3)
            Pixel values in the file's units.

        Raises
        ------
        ResponseError
            One line naming the key, its value and what the frame holds.
        """
        img = np.asarray(image)
        fs = self.full_scale(img)
        if img.dtype.kind in "ui" and fs > np.iinfo(img.dtype).max:
            raise ResponseError(f"response.clip: {fs:g} is above the largest value a {img.dtype} frame holds "
                                f"({np.iinfo(img.dtype).max}): its clipped pixels would not be seen")
        if img.dtype.kind == "f" and self.clip is not None and img.size:
            peak = float(img.max())
            if 0.0 < peak <= MIN_FLOAT_PEAK_OF_CLIP * fs:
                raise ResponseError(f"response.clip: {fs:g} is 255 or more times the float frame's largest value "
                                    f"({peak:g}): the frame's values are in other units than the clip level "
                                    f"(a frame scaled to 1 wants \"clip\": 1)")
        sample = img[::4, ::4]  # every 16th pixel: a share, not a count
        share = float(np.count_nonzero(sample > fs)) / max(sample.size, 1)
        if share > MAX_ABOVE_CLIP_SHARE:
            given = "" if self.clip is not None else " (not given: the dtype's maximum, 1 for floats)"
            raise ResponseError(f"response.clip: {fs:g}{given} is below {share:.0%} of the frame's pixel values "
                                f"(largest {float(sample.max()):g}): the clip level is in the file's units, "
                                f"255 for an 8-bit frame")

    def decode(self, v) -> np.ndarray:
        """The inverse tone curve alone of display values ``v`` (full scale 1, clipped to [0, 1]), float64."""
        v = np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0)
        if self.curve == "srgb":
            return srgb_inverse(v)
        return v ** self.gamma if self.curve == "gamma" else v

    def as_srgb(self, values, full_scale: float = 1.0) -> np.ndarray:
        """The values an sRGB sensor would have written for the light of ``values``: :meth:`decode`, then sRGB."""
        return srgb_encode(self.decode(np.asarray(values, np.float64) / full_scale)) * full_scale

    def linear(self, values, channel: int | None = None, full_scale: float = 1.0) -> np.ndarray:
        """Linear radiance (up to the exposure's unit) of pixel values, float64.

        ``values / full_scale`` through the inverse curve, over ``exposure`` and the white balance of ``channel``
        (their mean for ``channel`` None).
        """
        v = self.decode(np.asarray(values, dtype=np.float64) / full_scale)
        wb = float(np.mean(self.white_balance)) if channel is None else self.white_balance[channel]
        return v / (self.exposure * wb)

    def linearize(self, image, channel: str | int = "darkest") -> tuple[np.ndarray, float, int | None]:
        """The single-channel linear image a photometric fit runs on, and its clip level.

        Parameters
        ----------
        image : ndarray of shape (H, W) or (H, W, 3)
            Pixel values in the file's units (a grey image takes the white balance's mean).
        channel : "darkest" or int
            For an RGB image: the channel whose median linear value is least (a white highlight stands highest
            above the tissue there), or the index given.

        Returns
        -------
        linear : ndarray of shape (H, W), float64
            The channel's linear radiance.
        clip_linear : float
            The linear value of a clipped pixel: pixels at or above it are censored.
        channel : int or None
            The channel used (None for a grey image).

        Raises
        ------
        ResponseError
            A frame the response could not have written (:meth:`check_frame`).
        ValueError
            An image that is neither (H, W) nor (H, W, 3).
        """
        img = np.asarray(image)
        self.check_frame(img)
        fs = self.full_scale(img)
        if img.ndim == 2:
            return self.linear(img, None, fs), float(self.linear(fs, None, fs)), None
        if img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"image: need (H, W) or (H, W, 3), got shape {img.shape}")
        if channel == "darkest":
            med = [float(np.median(self.linear(img[::4, ::4, c], c, fs))) for c in range(3)]
            c = int(np.argmin(med))
        else:
            c = int(channel)
        return self.linear(img[..., c], c, fs), float(self.linear(fs, c, fs)), c


def video_response(sensor) -> SensorResponse:
    """The response of the 8-bit RGB video frame a scene's sensor makes (:func:`simtest.render.sensor.video_frame`).

    The sensor's tone curve, white balance and a clip of 255; the exposure is 1 (the fits' gains absorb the
    scale). Colour saturation and vignetting are not in the response's format.

    Parameters
    ----------
    sensor : simtest.scene.spec.SensorSpec

    Returns
    -------
    SensorResponse
    """
    if sensor.tone == "srgb":
        curve, gamma = "srgb", 1.0
    else:
        g = float(sensor.gamma)
        curve, gamma = ("linear", 1.0) if g == 1.0 else ("gamma", g)
    return SensorResponse(curve, gamma, tuple(float(v) for v in sensor.white_balance), 1.0, 255.0)


def _number(v, key: str, where: str) -> float:
    """``v`` as a float: a finite number > 0 within ``RANGES[key]``, else the one-line error naming ``where``."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and v > 0):
        raise ResponseError(f"{where}: must be a finite number > 0, got {v!r}")
    v = float(v)
    lo, hi, unit, _ = RANGES[key]
    if not lo <= v <= hi:
        raise ResponseError(f"{where}: {v!r} is outside its physical range [{lo:g}, {hi:g}] ({unit})")
    return v
