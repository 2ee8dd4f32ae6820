"""The sensor's response: how a scope's camera turns linear radiance into pixel values, and back.

A camera file's optional ``"response"`` object (:mod:`simtest.geometry.camera_file`)::

    "response": {"curve": "srgb", "white_balance": [1, 1, 1], "exposure": 1.0, "clip": 255}

- ``"curve"``: ``"linear"``, ``"srgb"`` (IEC 61966-2-1) or ``"gamma"`` (with ``"gamma"``: g, the
  curve ``s^(1 / g)``);
- ``"white_balance"``: per-channel multipliers [r, g, b] applied before the curve (default
  [1, 1, 1]);
- ``"exposure"``: a linear scale before the curve (default 1);
- ``"clip"``: the clip level in the file's units (default: the image dtype's maximum; 1 for float
  images).

The forward model is ``pixel = clip(curve(exposure * white_balance * radiance))`` with the curve's
output scaled to full scale (``clip``): the inverse (:meth:`SensorResponse.linearize`) gives the
radiance up to the exposure, per channel, so that a photometric fit runs on linear intensities.
No ``"response"`` means linear.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CURVES", "MAX_ABOVE_CLIP_SHARE", "MIN_FLOAT_PEAK_OF_CLIP", "RANGES", "ResponseError",
           "SensorResponse", "video_response"]

#: The tone curves a response may name.
CURVES = ("linear", "srgb", "gamma")
_KEYS = ("curve", "gamma", "white_balance", "exposure", "clip")
#: The largest share of a frame's pixel values above its response's clip level that
#: :meth:`SensorResponse.check_frame` accepts. A sensor's clip is its largest value; values above it
#: come from a decoder's overshoot near clipped areas, a few percent of a frame at most. A quarter
#: is far above that and far below the share a clip in the wrong units leaves (nearly all).
MAX_ABOVE_CLIP_SHARE = 0.25
#: A float frame's brightest pixel must be above this fraction of a ``"clip"`` the camera file
#: gives: one step of an 8-bit code (1/255, the coarsest quantisation a scope's video has). A float
#: frame whose every pixel lies within one 8-bit step of black at that clip level holds nothing a sensor at
#: that clip would tell from black: its values are in other units (a frame scaled to [0, 1] read
#: with ``"clip": 255``, which linearises it 255 times too dark and biased the depth by 6 %).
MIN_FLOAT_PEAK_OF_CLIP = 1.0 / 255.0

#: The physical range of each number of a ``"response"`` object: key -> (least, most, unit,
#: reason). A value outside is refused (one line naming the file, the key and the value).
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
        The exponent g of the ``"gamma"`` curve ``s^(1 / g)`` (> 0; 1 otherwise).
    white_balance : tuple of 3 float
        Per-channel multipliers before the curve (> 0).
    exposure : float
        Linear scale before the curve (> 0).
    clip : float or None
        Full scale in the file's units (the value of a saturated pixel); None: the dtype's
        maximum (1 for float images).
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
            Not an object, an unknown key, an unknown curve, a ``"gamma"`` curve without
            ``"gamma"``, a ``"gamma"`` key with another curve, a boolean, a non-positive or
            non-finite number, or a number outside its physical range (:data:`RANGES`); the
            message is one line naming ``where``, the key and the value.
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
            return _in_range(_positive(value.get(key, default), f"{where}.{key}"), key, f"{where}.{key}")

        wb = value.get("white_balance", [1.0, 1.0, 1.0])
        if not (isinstance(wb, list) and len(wb) == 3):
            raise ResponseError(f"{where}.white_balance: must be a list of 3 numbers, got {wb!r}")
        wbs = tuple(_in_range(_positive(v, f"{where}.white_balance"), "white_balance", f"{where}.white_balance")
                    for v in wb)
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

        The forward model clips every pixel at ``clip`` (module docstring), so a frame cannot
        hold values the clip level cannot reach, nor a large share above it:

        - an integer frame whose dtype's maximum is below ``clip``: no pixel reaches the clip,
          so clipped pixels would not be censored;
        - a float frame whose largest value is at most :data:`MIN_FLOAT_PEAK_OF_CLIP` of a given
          ``clip``: the frame and the clip level are in different units;
        - more than :data:`MAX_ABOVE_CLIP_SHARE` of the pixel values (every channel) above
          ``clip``: the level is not in the file's units (1 for an 8-bit frame, a fraction
          where 255 was meant). A decoder's overshoot (a JPEG's ringing at the edge of a clipped
          highlight, a video's values above its nominal white) puts some values above a clip
          below the dtype's maximum, only near clipped areas.

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
        """The inverse tone curve alone of display values ``v`` (full scale 1, clipped to [0, 1]):
        light in the frame's own channels (its white balance and exposure kept: the illuminant
        stays white), linear, 1 at full scale; float64."""
        v = np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0)
        if self.curve == "srgb":
            return srgb_inverse(v)
        return v ** self.gamma if self.curve == "gamma" else v

    def as_srgb(self, values, full_scale: float = 1.0) -> np.ndarray:
        """The values an sRGB sensor would have written for the light of ``values`` (``full_scale``
        white): :meth:`decode`, then the sRGB curve; float64, same full scale."""
        return srgb_encode(self.decode(np.asarray(values, np.float64) / full_scale)) * full_scale

    def linear(self, values, channel: int | None = None, full_scale: float = 1.0) -> np.ndarray:
        """Linear radiance (up to the exposure's unit) of pixel values, float64.

        ``values / full_scale`` through the inverse curve, over ``exposure`` and over the white
        balance of ``channel`` (the mean of the three for a grey image, ``channel`` None).
        """
        v = self.decode(np.asarray(values, dtype=np.float64) / full_scale)
        wb = float(np.mean(self.white_balance)) if channel is None else self.white_balance[channel]
        return v / (self.exposure * wb)

    def linearize(self, image, channel: str | int = "darkest") -> tuple[np.ndarray, float, int | None]:
        """The single-channel linear image a photometric fit runs on, and its clip level.

        Parameters
        ----------
        image : ndarray of shape (H, W) or (H, W, 3)
            Pixel values in the file's units. A grey image is taken as one channel with the white
            balance's mean.
        channel : "darkest" or int
            For an RGB image: the channel whose median linear value is least (where the tissue is
            darkest, so that a white highlight stands highest above its diffuse shading), or the
            channel index given.

        Returns
        -------
        linear : ndarray of shape (H, W), float64
            The channel's linear radiance (module docstring).
        clip_linear : float
            The linear value of a clipped pixel of that channel: pixels at or above it are
            censored (the radiance is at least this).
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
        # pixel values at full scale are censored: their radiance is at least the clip's
        return self.linear(img[..., c], c, fs), float(self.linear(fs, c, fs)), c


def video_response(sensor) -> SensorResponse:
    """The response of the 8-bit RGB video frame a scene's sensor makes
    (:func:`simtest.render.sensor.video_frame`): what ``simtest render`` writes into its camera file.

    The tone curve (``tone`` "srgb", else ``gamma``: "linear" at 1, "gamma" otherwise), the white
    balance and the clip level (255, the 8-bit full scale) are the sensor's. The frame clips at
    ``saturation`` and scales that to full scale, so the response's linear values are the
    radiance times the frame's exposure over the saturation: the exposure is left at 1, a scale
    of the linear image that the fits' gains absorb (an automatic exposure changes from frame to
    frame). The sensor's colour saturation (a mix of the channels) and vignetting (a smooth gain
    over the frame) are not in the response's format.

    Parameters
    ----------
    sensor : simtest.scene.spec.SensorSpec
        The scene's sensor (its ``tone``, ``gamma`` and ``white_balance``).

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


def _in_range(v: float, key: str, where: str) -> float:
    lo, hi, unit, why = RANGES[key]
    if not lo <= v <= hi:
        raise ResponseError(f"{where}: {v!r} is outside its physical range [{lo:g}, {hi:g}] ({unit})")
    return v


def _positive(v, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and v > 0):
        raise ResponseError(f"{where}: must be a finite number > 0, got {v!r}")
    return float(v)
