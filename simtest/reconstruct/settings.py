"""Reconstruction settings: one frozen value, validated once where it is made (``__post_init__``,
also after :meth:`ReconSettings.replace`), passed from the caller to marching squares.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from simtest.decisions import BRIGHTNESS_REL, FRAME_ISOVALUES, MIN_AREA_PX, PEAK_REL

__all__ = ["MAX_CANDIDATES", "Normalisation", "ReconSettings", "SettingError", "validate_isovalues"]


class Normalisation(enum.StrEnum):
    """What the isovalue t is relative to (paper section 3.1, step 4, and beyond).

    Members compare equal to their string values, which ``estimates.json`` and the command line use.
    """

    #: t relative to the BP intensity: the isophote at ``t I_bp`` (the paper's normalisation).
    BP = "bp"
    #: t relative to the image's full scale: the harness's paper protocol (images 1 at the BP).
    FULL_SCALE = "full_scale"
    #: t relative to the BP's height above the ROI border's median b: the isophote at ``b + t (I_bp - b)``,
    #: for highlights on bright tissue (beyond the paper).
    LOCAL = "local"
    #: LOCAL where the median of the ROI border is at least :data:`AUTO_LOCAL_BACKGROUND_REL` of
    #: the BP intensity (a highlight on bright tissue), else BP (the default for whole frames).
    AUTO = "auto"


class SettingError(ValueError):
    """A setting refused: ``setting`` its :class:`ReconSettings` field, ``reason`` what is wrong with the value (shown);
    the message ``"<setting>: <reason>"`` (a command line names the option: ``reconstruct.cli.option_message``)."""

    def __init__(self, setting: str, reason: str):
        super().__init__(f"{setting}: {reason}")
        self.setting, self.reason = setting, reason


#: Candidate detection methods (see :func:`simtest.reconstruct.detect.detect_specularities`).
DETECTION_METHODS = ("local_peak", "full_scale")


def validate_isovalues(isovalues) -> tuple[float, ...]:
    """Check isovalues: one t or several, each finite and strictly inside (0, 1).

    Parameters
    ----------
    isovalues : float or sequence of float
        One isovalue or several, the primary first.

    Returns
    -------
    tuple of float
        The isovalues in the order given (at least one).

    Raises
    ------
    SettingError
        A ValueError, if the sequence is empty, a value is not a number or lies outside (0, 1), or a
        value is given twice; the message starts with ``isovalues:`` and shows the value.
    """
    if isinstance(isovalues, (str, bytes)):
        raise SettingError("isovalues", f"{isovalues!r} is not a number")
    vals = [isovalues] if np.ndim(isovalues) == 0 else list(np.asarray(isovalues, dtype=object).ravel())
    if not vals:
        raise SettingError("isovalues", "an empty sequence was given; need at least one t in (0, 1)")
    out = []
    for v in vals:
        try:
            t = float(v)
        except (TypeError, ValueError):
            raise SettingError("isovalues", f"{v!r} is not a number") from None
        if not (math.isfinite(t) and 0.0 < t < 1.0):
            raise SettingError("isovalues", f"{t!r} is outside the open interval (0, 1)")
        if t in out:  # the same isophote twice would count twice in the joint cone axis
            raise SettingError("isovalues", f"{t!r} is given twice; give each isovalue once")
        out.append(t)
    return tuple(out)


def _positive_or_none(name: str, value) -> float | None:
    if value is None:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SettingError(name, f"{value!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise SettingError(name, f"must be finite and positive, got {value!r}")
    return v


def _number(value) -> float:
    """``float(value)``; NaN (refused by every range) for a bool or what is not a number."""
    if isinstance(value, bool):
        return float("nan")
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


#: Detection's default cap on the bright components examined: None, every one.
MAX_CANDIDATES = None


@dataclass(frozen=True)
class ReconSettings:
    """Every setting of the reconstruction, validated once when made.

    ``ReconSettings()`` holds the paper's settings (a known highlight); :meth:`for_frames` the
    defaults for whole frames.

    Parameters
    ----------
    isovalues : float or sequence of float
        Isovalue(s) t in (0, 1), stored as a tuple; the first is the *primary* isovalue, the others
        nested isophotes for the joint cone axis.
    normalise : Normalisation or {"bp", "full_scale", "local", "auto"}
        Intensity normalisation, see :class:`Normalisation` (stored as the enum).
    smooth_sigma_px : float or None
        Gaussian smoothing sigma, px, before detection and contouring; 0 for none; None: chosen from
        the noise (:func:`~simtest.reconstruct.detect.smooth_sigma_for_noise`). Finite, in [0, 100].
    allow_open : bool
        Fit an isophote cut by the ROI or image border (flagged ``closed=False``).
    full_scale : float, optional
        Intensity of a white pixel; default the dtype maximum (uint) or ``max(1, image.max())``
        (float). Finite and positive.
    saturation_level : float, optional
        A pixel is clipped when every channel is >= this; default the frame's ceiling (its dtype's
        maximum, or where a JPEG's clipped tops decode: ``frame_ceiling``); none for float images; finite, positive.
    brightness_rel : float
        Detection: a pixel is bright when its luma is >= ``brightness_rel * full_scale``; in (0, 1).
    min_area_px : int
        Detection: bright components smaller than this are rejected as ``too_small``; >= 1.
    detection : {"full_scale", "local_peak"}
        Detection method (:func:`~simtest.reconstruct.detect.detect_specularities`).
    peak_rel : float
        Detection with ``"local_peak"``: the fraction of each local peak's height that cuts out its
        component; in (0, 1).
    max_candidates : int or None
        Detection examines at most this many bright components, the largest first (those left out
        are counted and reported); None: every one.
    verify : bool
        Judge every fitted candidate by the checks of :mod:`simtest.reconstruct.verify` and give it
        a ``confidence``; a failed check's reason becomes the status.
    min_confidence : float or None
        With ``verify``: a fit that passes every check with a ``confidence`` below this gets
        ``low_confidence``; in [0, 1]. None: :func:`~simtest.reconstruct.frame_verify.default_min_confidence`.

    Raises
    ------
    SettingError
        A ValueError naming the field and the value, for any value outside the ranges above.

    Examples
    --------
    >>> s = ReconSettings(isovalues=[0.1, 0.3], normalise="local")
    >>> s.isovalues, s.normalise is Normalisation.LOCAL
    ((0.1, 0.3), True)
    >>> s.replace(isovalues=0.5).isovalues
    (0.5,)
    >>> ReconSettings(isovalues=1.5)  # doctest: +IGNORE_EXCEPTION_DETAIL
    Traceback (most recent call last):
    ...
    SettingError: isovalues: 1.5 is outside the open interval (0, 1)
    """

    isovalues: tuple[float, ...] = (0.1,)
    normalise: Normalisation = Normalisation.BP
    smooth_sigma_px: float = 0.0
    allow_open: bool = False
    full_scale: float | None = None
    saturation_level: float | None = None
    brightness_rel: float = BRIGHTNESS_REL
    min_area_px: int = MIN_AREA_PX
    detection: str = "full_scale"
    peak_rel: float = PEAK_REL
    max_candidates: int | None = MAX_CANDIDATES
    verify: bool = False
    min_confidence: float | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "isovalues", validate_isovalues(self.isovalues))
        try:
            set_(self, "normalise", Normalisation(self.normalise))
        except ValueError:
            modes = tuple(m.value for m in Normalisation)
            raise SettingError("normalise", f"{self.normalise!r} is not one of {modes}") from None
        if self.smooth_sigma_px is not None:
            sigma = _number(given := self.smooth_sigma_px)
            if not (math.isfinite(sigma) and 0.0 <= sigma <= 100.0):
                raise SettingError("smooth_sigma_px", f"must be finite and in [0, 100] px, got {given!r}")
            set_(self, "smooth_sigma_px", sigma)
        if self.detection not in DETECTION_METHODS:
            raise SettingError("detection", f"{self.detection!r} is not one of {DETECTION_METHODS}")
        prel = _number(self.peak_rel)
        if not 0.0 < prel < 1.0:
            raise SettingError("peak_rel", f"must be in (0, 1), got {self.peak_rel!r}")
        set_(self, "peak_rel", prel)
        for name in ("allow_open", "verify"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise SettingError(name, f"must be true or false, got {getattr(self, name)!r}")
            set_(self, name, bool(getattr(self, name)))
        if self.min_confidence is not None:
            conf = _number(self.min_confidence)
            if not 0.0 <= conf <= 1.0:
                raise SettingError("min_confidence", f"must be in [0, 1] or None, got {self.min_confidence!r}")
            set_(self, "min_confidence", conf)
        set_(self, "full_scale", _positive_or_none("full_scale", self.full_scale))
        set_(self, "saturation_level", _positive_or_none("saturation_level", self.saturation_level))
        rel = _number(self.brightness_rel)
        if not 0.0 < rel < 1.0:
            raise SettingError("brightness_rel", f"must be in (0, 1), got {self.brightness_rel!r}")
        set_(self, "brightness_rel", rel)
        if isinstance(self.min_area_px, bool) or not float(self.min_area_px).is_integer() or self.min_area_px < 1:
            raise SettingError("min_area_px", f"must be an integer >= 1, got {self.min_area_px!r}")
        set_(self, "min_area_px", int(self.min_area_px))
        if self.max_candidates is not None:
            if (not isinstance(self.max_candidates, (int, float, np.integer, np.floating))
                    or isinstance(self.max_candidates, bool) or not float(self.max_candidates).is_integer()
                    or self.max_candidates < 1):
                raise SettingError("max_candidates", f"must be an integer >= 1 or None (every component), "
                                                   f"got {self.max_candidates!r}")
            set_(self, "max_candidates", int(self.max_candidates))

    @classmethod
    def for_frames(cls, **changes) -> ReconSettings:
        """The defaults for whole frames: detection relative to local peaks, smoothing chosen from the
        noise, ``normalise="auto"``, isovalues :data:`FRAME_ISOVALUES`; ``changes`` applied on top.
        """
        base = cls(isovalues=FRAME_ISOVALUES, normalise=Normalisation.AUTO, smooth_sigma_px=None,
                   detection="local_peak", verify=True)
        return base.replace(**changes) if changes else base

    def replace(self, **changes) -> ReconSettings:
        """A copy with some fields changed, validated again.

        Raises
        ------
        ValueError
            For an unknown field name or a bad value.
        """
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - names)
        if unknown:
            hints = [m for u in unknown for m in difflib.get_close_matches(u, names, n=1)]
            hint = f" (did you mean {', '.join(hints)}?)" if hints else ""
            raise ValueError(f"unknown reconstruction setting(s) {', '.join(unknown)}{hint}; "
                             f"known: {', '.join(sorted(names))}")
        return dataclasses.replace(self, **changes)

    @classmethod
    def make(cls, settings: ReconSettings | None = None, isovalues: float | Sequence[float] | None = None,
             *, frames: bool = False, **options) -> ReconSettings:
        """``settings`` (default ``ReconSettings()``, or :meth:`for_frames` with ``frames``) with
        ``isovalues`` and ``options`` applied."""
        base = _default_settings(cls, frames) if settings is None else settings
        if not isinstance(base, cls):
            raise ValueError(f"settings must be a ReconSettings, got {type(base).__name__}")
        if isovalues is not None:
            options["isovalues"] = isovalues
        return base.replace(**options) if options else base

    def to_dict(self) -> dict:
        """Plain JSON-ready values (``normalise`` as its string)."""
        d = dataclasses.asdict(self)
        d["isovalues"] = list(self.isovalues)
        d["normalise"] = self.normalise.value
        return d


@functools.cache
def _default_settings(cls: type, frames: bool) -> ReconSettings:
    """``cls()`` or ``cls.for_frames()``, built once (frozen: shared by every call)."""
    return cls.for_frames() if frames else cls()
