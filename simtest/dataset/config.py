"""Dataset configuration: a TOML file naming scene families and the distributions to draw from.

A config is parsed and fully validated before any file is written; every error is a
:class:`DatasetConfigError` naming the file, the key and the value. Top-level keys: ``count``
(0 .. :data:`MAX_COUNT`), ``seed``, ``shard_size``, ``isovalues`` (t in (0, 1)), ``variant``,
``compress``, ``splits``, ``auto_exposure``; tables ``[families]`` (relative weights) and
``[params]`` (shared distributions) with ``[params.<family>]`` overrides. See
``scenes/datasets/example.toml``.

Distributions: a bare value (constant), ``constant`` (``value``), ``uniform`` (``low``, ``high``;
inclusive for integer parameters), ``loguniform`` (``low > 0``, ``high``), ``normal`` (``mean``,
``std``, optional ``low``/``high`` clipping, required where the domain is bounded) and ``choice``
(``values``, optional ``weights``). The parameters, units, domains and defaults are in
:data:`PARAMS` (``simtest dataset params``).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import Field
from pydantic.dataclasses import dataclass as pydantic_dataclass

from simtest._checks import format_value, keyed_error
from simtest._config import CONFIG, Bool, Int, Num, Scalar, Str, parse_toml, validated
from simtest._io import jsonable
from simtest.scene.spec import Variant

__all__ = ["FAMILIES", "MAX_COUNT", "PARAMS", "DatasetConfig", "DatasetConfigError", "Dist", "ParamDef",
           "config_from_dict", "load_config"]

#: Scene families, in the canonical order used for the seeded family draw.
FAMILIES: tuple[str, ...] = ("planes", "spheres", "cylinders", "colon", "liver")

#: Default seeded split fractions (train, val, test).
DEFAULT_SPLITS = (("train", 0.8), ("val", 0.1), ("test", 0.1))

#: Default auto-exposure: the ``percentile`` of the linear image inside the mask is brought to
#: ``level`` of full scale before the sensor model (``exposure`` multiplies on top). 99.9 lets at most
#: 0.1 % of surface pixels saturate (99.5 saturated small highlights' isophotes); 0.9 leaves headroom.
DEFAULT_AUTO_EXPOSURE = (99.9, 0.9)
_MAX_SHARD = 100_000
#: Most samples a config may ask for: the manifest (~4 KB a row) is read whole, so 10 million rows
#: are ~40 GB in memory (and ~17 TB of shards); a larger count is a typo.
MAX_COUNT = 10_000_000


class DatasetConfigError(ValueError):
    """A dataset config is invalid; the message reads ``<file>: <key>: <reason>``."""


@dataclass(frozen=True)
class Dist:
    """One distribution of a scalar parameter.

    Attributes
    ----------
    kind : str
        ``"constant"``, ``"uniform"``, ``"loguniform"``, ``"normal"`` or ``"choice"``.
    args : tuple
        ``(value,)``, ``(low, high)``, ``(low, high)``, ``(mean, std, low, high)`` (low/high may
        be None) or ``(values, weights)`` (weights may be None) respectively.
    """

    kind: str
    args: tuple

    def support(self) -> tuple[float, float] | None:
        """Closed interval ``(low, high)`` that holds every draw, in the parameter's unit
        (``-inf``/``inf`` for an unclipped normal); None for a constant or choice that is not numeric."""
        if self.kind == "constant":
            v = self.args[0]
            return (v, v) if _is_number(v) else None
        if self.kind in ("uniform", "loguniform"):
            return (self.args[0], self.args[1])
        if self.kind == "normal":
            mean, std, low, high = self.args
            lo = low if low is not None else (-math.inf if std > 0 else mean)
            hi = high if high is not None else (math.inf if std > 0 else mean)
            return (lo, hi)
        values = self.args[0]
        return (min(values), max(values)) if all(_is_number(v) for v in values) else None

    def draw(self, rng: np.random.Generator, integer: bool = False):
        """Draw one value with ``rng`` (constants draw nothing from the stream).

        Parameters
        ----------
        rng : numpy.random.Generator
            The sample's generator.
        integer : bool
            Draw an integer (uniform: inclusive bounds; normal: rounded after clipping).

        Returns
        -------
        float, int, str or bool
            A plain Python scalar (JSON-ready).
        """
        kind, a = self.kind, self.args
        if kind == "constant":
            v = a[0]
        elif kind == "uniform":
            v = int(rng.integers(int(a[0]), int(a[1]) + 1)) if integer else float(rng.uniform(a[0], a[1]))
        elif kind == "loguniform":
            v = float(np.exp(rng.uniform(np.log(a[0]), np.log(a[1]))))
        elif kind == "normal":
            mean, std, low, high = a
            v = float(rng.normal(mean, std))
            v = float(np.clip(v, -np.inf if low is None else low, np.inf if high is None else high))
        else:
            values, weights = a
            p = None if weights is None else np.asarray(weights, float) / float(np.sum(weights))
            v = values[int(rng.choice(len(values), p=p))]
        if integer:
            return int(round(v))
        return v if isinstance(v, bool | str) else float(v)

    def as_dict(self) -> dict:
        """JSON/TOML-ready form (the inverse of the config syntax)."""
        names = _DIST_KEYS[self.kind]
        out: dict[str, Any] = {"dist": self.kind}
        for name, value in zip(names, self.args, strict=True):
            if value is not None:
                out[name] = list(value) if isinstance(value, tuple) else value
        return out


def _const(v) -> Dist:
    return Dist("constant", (v,))


def _uni(lo, hi) -> Dist:
    return Dist("uniform", (lo, hi))


@dataclass(frozen=True)
class ParamDef:
    """A parameter a dataset config may draw.

    Attributes
    ----------
    name : str
        Config key (unit suffix in the name where a unit could be mistaken).
    doc : str
        Meaning, unit and frame.
    families : tuple of str
        Families that use it.
    default : dict
        Default distribution per family (key ``"*"`` for all families).
    domain : (float, float)
        Closed interval every draw must lie in (``-inf``/``inf`` for unbounded sides);
        ``open_low``/``open_high`` make an end exclusive.
    integer : bool
        Integer-valued parameter.
    choices : tuple of str, optional
        Allowed values of a string parameter.
    """

    name: str
    doc: str
    families: tuple[str, ...]
    default: dict
    domain: tuple[float, float] = (-math.inf, math.inf)
    open_low: bool = False
    open_high: bool = False
    integer: bool = False
    choices: tuple[str, ...] | None = None

    def default_for(self, family: str) -> Dist:
        """The default distribution for ``family`` (one of :data:`FAMILIES`): its own, else the
        ``"*"`` one, else None (the parameter is not used by that family)."""
        return self.default.get(family, self.default.get("*"))


_ALL = FAMILIES

#: Every parameter a config may set, in the canonical draw order.
PARAMS: tuple[ParamDef, ...] = (
    # --- camera, render ---------------------------------------------------------------------
    ParamDef("resolution_px", "square image size M (pixels); K = [[f,0,M/2-0.5],[0,f,M/2-0.5],[0,0,1]]",
             _ALL, {"*": _const(256)}, (8, 4096), integer=True),
    ParamDef("spp", "samples per pixel", _ALL, {"*": _const(16)}, (1, 65536), integer=True),
    ParamDef("fov_deg", "full horizontal field of view (degrees); endoscopes have 140 to 170",
             _ALL, {"*": _const(140.0)}, (0.0, 179.0), open_low=True),
    # --- material ---------------------------------------------------------------------------
    ParamDef("phong_n", "Phong exponent n (roughness; larger is shinier), paper eq. 1",
             _ALL, {"*": _uni(30.0, 120.0)}, (0.0, math.inf), open_low=True),
    ParamDef("phong_c", "Phong specular coefficient c", _ALL, {"*": _const(1.0)}, (0.0, math.inf),
             open_low=True),
    ParamDef("diffuse_albedo", "diffuse (Lambertian) albedo of the tissue, 0 for pure specular",
             _ALL, {"*": _uni(0.0, 0.3)}, (0.0, 1.0)),
    # --- light ------------------------------------------------------------------------------
    ParamDef("light_offset_mm", "light offset epsilon (mm): L = V + epsilon (cos a, sin a, b)",
             _ALL, {"*": _const(0.0)}, (0.0, math.inf)),
    ParamDef("light_offset_a_deg", "direction a of the light offset (degrees)", _ALL,
             {"*": _uni(0.0, 360.0)}, (-360.0, 720.0)),
    ParamDef("light_offset_b", "axial component b of the light offset (dimensionless)", _ALL,
             {"*": _const(0.0)}),
    ParamDef("light_falloff", "\"cancel\": the specular image is intensity x Phong eq. 1 exactly (the "
             "diffuse part keeps its 1/d^2); \"keep\": both fall as 1/d^2 (d in mm), as in an endoscope",
             _ALL, {"*": _const("cancel")}, choices=("cancel", "keep")),
    ParamDef("light_intensity", "radiant intensity of the point light (arbitrary units); with the falloff "
             "kept, radiance is intensity x BRDF / d^2 with d in mm, so intensity ~ d^2 gives a "
             "specular peak near 1", _ALL, {"*": _const(1.0)}, (0.0, math.inf), open_low=True),
    # --- sensor -----------------------------------------------------------------------------
    ParamDef("exposure", "exposure multiplier applied to the linear image before clipping", _ALL,
             {"*": _const(1.0)}, (0.0, math.inf), open_low=True),
    ParamDef("saturation", "clip level of the sensor, as a fraction of full scale", _ALL,
             {"*": _const(1.0)}, (0.0, 1.0), open_low=True),
    ParamDef("noise_sigma", "Gaussian read-noise standard deviation, fraction of full scale", _ALL,
             {"*": _const(0.0)}, (0.0, 1.0)),
    ParamDef("full_well_e", "electrons at full scale for Poisson shot noise (0: none)", _ALL,
             {"*": _const(0.0)}, (0.0, math.inf)),
    ParamDef("gamma", "sensor gamma: output = clipped^(1/gamma)", _ALL, {"*": _const(1.0)},
             (0.0, math.inf), open_low=True),
    # --- geometry: analytic surfaces --------------------------------------------------------
    ParamDef("distance_mm", "distance (mm) from the camera centre to the plane (planes), to the "
             "nearest point of the sphere or cylinder, or to the liver surface point it looks at",
             ("planes", "spheres", "cylinders", "liver"),
             {"*": _uni(20.0, 60.0), "liver": _uni(20.0, 80.0)}, (0.0, math.inf), open_low=True),
    ParamDef("view_angle_deg", "angle between the optical axis and the surface normal (planes), the "
             "cylinder axis' tilt off the image plane (cylinders), the sphere centre's angle off "
             "axis (spheres), the optical axis' angle off the centre-line tangent (colon), or the "
             "viewing line's angle off the surface normal at the target point (liver)", _ALL,
             {"*": _uni(0.0, 58.0), "colon": _uni(20.0, 70.0), "liver": _uni(0.0, 50.0)},
             (0.0, 90.0), open_high=True),
    ParamDef("azimuth_deg", "azimuth of the tilt about the optical axis (planes, spheres, cylinders, "
             "colon) or of the target point about the liver centre (liver), degrees", _ALL,
             {"*": _uni(0.0, 360.0)}, (-360.0, 720.0)),
    ParamDef("radius_mm", "sphere or cylinder radius (mm)", ("spheres", "cylinders"),
             {"*": Dist("loguniform", (10.0, 200.0))}, (0.0, math.inf), open_low=True),
    # --- geometry: colon --------------------------------------------------------------------
    ParamDef("station", "camera position along the colon centre line, fraction of its arc length",
             ("colon",), {"*": _uni(0.15, 0.85)}, (0.0, 1.0)),
    ParamDef("radial_offset", "camera offset from the centre line, fraction of the smallest wall "
             "distance of the local ring (so the camera stays in the lumen)",
             ("colon",), {"*": _uni(0.0, 0.5)}, (0.0, 1.0), open_high=True),
    ParamDef("roll_deg", "roll of the image about the optical axis (degrees)", ("colon", "liver"),
             {"*": _uni(0.0, 360.0)}, (-360.0, 720.0)),
    # --- geometry: liver --------------------------------------------------------------------
    ParamDef("elevation_deg", "elevation of the target point about the liver centre (degrees)", ("liver",),
             {"*": _uni(-60.0, 60.0)}, (-90.0, 90.0)),
    # --- appearance: the virtual endoscope ----------------------------------------------------
    # (last, so that configs written before these existed draw the same values)
    ParamDef("appearance", "\"phong\": grey Phong surface (paper eq. 1, `phong_c`, `phong_n`, "
             "`diffuse_albedo`), one-channel sensor image; \"tissue\": the virtual endoscope's "
             "procedural RGB tissue (mucosa; liver on the liver family) under a wet film whose lobe "
             "(`tissue_lobe`) has the roughness matching `phong_n`, with `relief_mm` of micro-relief, "
             "made into an sRGB video frame (3 channels)", _ALL, {"*": _const("phong")},
             choices=("phong", "tissue")),
    ParamDef("tissue_lobe", "specular lobe of the tissue's wet film (appearance \"tissue\"): \"ggx\", "
             "\"beckmann\" (alpha = sqrt(2 / (4 phong_n + 2))) or \"phong\" (exponent phong_n)",
             _ALL, {"*": _const("ggx")}, choices=("ggx", "beckmann", "phong")),
    ParamDef("relief_mm", "RMS height of the tissue's micro-relief (mm; appearance \"tissue\"; 0: "
             "smooth, so the highlight labels of the smooth surface hold)", _ALL, {"*": _const(0.0)},
             (0.0, 1.0)),
    ParamDef("light_rig", "\"point\": one point light at the light offset (`light_offset_*`); "
             "\"colonoscope\": two light guides 4 mm either side of the lens; \"laparoscope\": a "
             "ring of 8 lights of radius 4 mm. A rig moves with the camera, keeps the 1/d^2 falloff "
             "and ignores `light_offset_*` and `light_falloff`; `light_intensity` scales each light",
             _ALL, {"*": _const("point")}, choices=("point", "colonoscope", "laparoscope")),
    ParamDef("colon_mesh", "bundled colon mesh: \"colon\" (smooth tube) or \"colon_haustral\" (semilunar "
             "folds, taeniae, haustra: the `colonoscope` scene's)", ("colon",),
             {"*": _const("colon")}, choices=("colon", "colon_haustral")),
)

_PARAM_BY_NAME = {p.name: p for p in PARAMS}


@dataclass(frozen=True)
class DatasetConfig:
    """A validated dataset config.

    Attributes
    ----------
    count, seed, shard_size : int
        Number of samples (0 .. :data:`MAX_COUNT`), root seed (sample i draws from
        ``SeedSequence([seed, i])``), samples per shard.
    isovalues : tuple of float
        Isophote levels t in (0, 1), relative to the Phong peak c.
    variant : str
        Mitsuba variant or ``"auto"``.
    compress : bool
        Deflate :data:`simtest.dataset.shards.DEFLATED` in the shard files (default True).
    families : tuple of (str, float)
        Families with positive weight, in canonical order.
    params : dict
        ``{family: {param: Dist}}`` with every parameter the family uses (defaults filled in).
    source : str
        Where the config came from (file path or ``"<dict>"``), for messages.
    raw : dict
        The config as given (JSON-ready), kept in the dataset card.
    splits : tuple of (str, float)
        Fractions of ``train``, ``val`` and ``test`` (summing to 1); see :meth:`split_of`.
    auto_exposure : (float, float) or None
        ``(percentile, level)``: scale each linear image so that this percentile of its surface
        pixels reaches ``level`` x full scale before the sensor model; None: exposure as drawn.
    """

    count: int
    seed: int
    shard_size: int
    isovalues: tuple[float, ...]
    variant: str
    compress: bool
    families: tuple[tuple[str, float], ...]
    params: dict = field(hash=False)
    source: str = "<dict>"
    raw: dict = field(default_factory=dict, hash=False, compare=False)
    splits: tuple[tuple[str, float], ...] = DEFAULT_SPLITS
    auto_exposure: tuple[float, float] | None = DEFAULT_AUTO_EXPOSURE

    @property
    def n_shards(self) -> int:
        """Number of shards (the last one may be short)."""
        return -(-self.count // self.shard_size)

    def shard_range(self, shard: int) -> range:
        """Sample indices held by ``shard``: ``shard * shard_size`` up to ``min(count, (shard + 1) *
        shard_size)`` (exclusive); empty for a shard number past the end."""
        start = shard * self.shard_size
        return range(start, min(self.count, start + self.shard_size))

    def split_of(self, index: int) -> str:
        """The split of sample ``index``: a pure function of ``(seed, index)``.

        Parameters
        ----------
        index : int
            Sample index.

        Returns
        -------
        str
            ``"train"``, ``"val"`` or ``"test"``: ``u = sha256("<seed>:<index>")`` read as a fraction
            in [0, 1) picks the first split whose cumulative fraction exceeds it, so a sample keeps
            its split when ``count`` grows (and the realised fractions tend to :attr:`splits`).
        """
        digest = hashlib.sha256(f"simtest-split:{self.seed}:{int(index)}".encode()).digest()
        u = int.from_bytes(digest[:8], "big") / 2.0**64
        acc = 0.0
        for name, frac in self.splits:
            acc += frac
            if u < acc:
                return name
        return self.splits[-1][0]

    def to_dict(self) -> dict:
        """Canonical, complete JSON-ready form (defaults filled in); ``config_from_dict`` reads it."""
        used = {f for f, _ in self.families}
        return {"count": self.count, "seed": self.seed, "shard_size": self.shard_size,
                "isovalues": list(self.isovalues), "variant": self.variant, "compress": self.compress,
                "splits": dict(self.splits),
                "auto_exposure": (None if self.auto_exposure is None else
                                  {"percentile": self.auto_exposure[0], "level": self.auto_exposure[1]}),
                "families": {f: w for f, w in self.families},
                "params": {f: {k: d.as_dict() for k, d in self.params[f].items()} for f in FAMILIES if f in used}}

    def fingerprint(self) -> str:
        """64 hex digits of ``sha256(json.dumps(to_dict(), sort_keys=True))`` (compact separators):
        two configs that draw the same samples share it."""
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


#: ``_err(source, key, reason[, value])``: the one-line error of a bad key (:func:`simtest._checks.keyed_error`).
_err = functools.partial(keyed_error, DatasetConfigError)
#: The config's tables: frozen pydantic dataclasses, unknown keys refused.
_model = functools.partial(pydantic_dataclass, frozen=True, config=CONFIG)
_Weight = Annotated[Num, Field(ge=0.0)]  # a relative weight: never negative


@_model
class _Uniform:
    """``uniform`` or ``loguniform`` (``low > 0``) between ``low`` and ``high``."""

    dist: Str
    low: Num
    high: Num


@_model
class _Normal:
    """``normal``, clipped to ``[low, high]`` where given."""

    dist: Str
    mean: Num
    std: Num = Field(ge=0.0)  # a spread: never negative
    low: Num | None = None
    high: Num | None = None


@_model
class _Choice:
    """``choice`` among ``values`` (finite scalars), with ``weights`` (non-negative) or uniformly."""

    dist: Str
    values: list[Scalar] = Field(min_length=1)
    weights: list[_Weight] | None = None


@_model
class _Constant:
    """``constant``: always ``value``."""

    dist: Str
    value: Any


_DIST_MODELS = {"constant": _Constant, "uniform": _Uniform, "loguniform": _Uniform,
                "normal": _Normal, "choice": _Choice}
#: Each distribution's keys, in the order of :attr:`Dist.args`.
_DIST_KEYS = {k: tuple(f for f in m.__dataclass_fields__ if f != "dist") for k, m in _DIST_MODELS.items()}


@_model
class _Exposure:
    """``auto_exposure``: bring the ``percentile`` of the surface pixels to ``level`` of full scale."""

    percentile: Num = Field(gt=0.0, le=100.0)  # a percentile, percent
    level: Num = Field(gt=0.0, le=1.0)  # a fraction of full scale


@_model
class _Splits:
    """``splits``: fractions of the samples in each split."""

    train: Num = Field(ge=0.0, le=1.0)
    val: Num = Field(ge=0.0, le=1.0)
    test: Num = Field(ge=0.0, le=1.0)


@_model
class _File:
    """The config file's top level (the families and parameters are checked by their names)."""

    count: Int = Field(ge=0, le=MAX_COUNT)
    seed: Int = Field(ge=0)
    shard_size: Int = Field(256, ge=1, le=_MAX_SHARD)
    # isophote levels t relative to the Phong peak: a closed isophote inside the highlight
    isovalues: list[Annotated[Num, Field(gt=0.0, lt=1.0)]] = Field(default_factory=lambda: [0.1],
                                                                    min_length=1)
    variant: Variant = "auto"
    compress: Bool = True
    splits: _Splits = _Splits(**dict(DEFAULT_SPLITS))
    auto_exposure: Any = None
    families: dict[str, Any] = Field(default_factory=dict)
    params: dict[str, Any] = Field(default_factory=dict)


def _parse_dist(value, key: str, source: str) -> Dist:
    """Parse one distribution entry (bare scalar or inline table)."""
    if not isinstance(value, dict):
        if isinstance(value, list):
            raise _err(source, key, "a list is not a distribution; write {dist = \"choice\", values = [...]}", value)
        return _const(validated(Scalar, value, DatasetConfigError, source, key))
    if "dist" not in value:
        raise _err(source, key, "distribution table needs `dist` (one of " + ", ".join(_DIST_KEYS) + ")", value)
    kind = value["dist"]
    if kind not in _DIST_KEYS:
        raise _err(source, f"{key}.dist", "unknown distribution (known: " + ", ".join(_DIST_KEYS) + ")", kind)
    if kind == "constant":
        if "value" not in value:
            raise _err(source, f"{key}.value", "required by a constant distribution")
        return _parse_dist(value["value"], key, source)
    d = validated(_DIST_MODELS[kind], value, DatasetConfigError, source, key)
    low, high = getattr(d, "low", None), getattr(d, "high", None)
    if low is not None and high is not None and low > high:
        raise _err(source, key, f"impossible range: low > high ({format_value(low)} > {format_value(high)})", value)
    if kind == "loguniform" and low <= 0:
        raise _err(source, f"{key}.low", "a loguniform distribution needs low > 0", low)
    if kind in ("uniform", "loguniform"):
        return Dist(kind, (low, high))
    if kind == "normal":
        return Dist(kind, (d.mean, d.std, low, high))
    if d.weights is not None and (len(d.weights) != len(d.values) or sum(d.weights) <= 0):
        raise _err(source, f"{key}.weights", f"must be {len(d.values)} non-negative numbers with a "
                   "positive sum", value["weights"])
    return Dist("choice", (tuple(value["values"]), None if d.weights is None else tuple(value["weights"])))


def _check_domain(p: ParamDef, dist: Dist, key: str, source: str) -> None:
    """Refuse a distribution whose draws can leave the parameter's domain."""
    values = {"constant": dist.args[:1], "choice": dist.args[0]}.get(dist.kind)
    show = dist.args[0] if dist.kind == "constant" else dist.as_dict()
    if p.choices is not None:
        if values is None or any(v not in p.choices for v in values):
            raise _err(source, key, "must be one of " + ", ".join(json.dumps(c) for c in p.choices)
                       + " (constant or choice)", show)
        return
    if values is not None and not all(_is_number(v) for v in values):
        raise _err(source, key, "must be a number", show)
    if p.integer:
        if dist.kind == "loguniform":
            raise _err(source, key, "an integer parameter takes constant, uniform, normal or choice", dist.as_dict())
        check = values if values is not None else list(dist.args[:2]) if dist.kind == "uniform" else []
        if any(float(v) != int(v) for v in check):
            raise _err(source, key, "must be an integer", show)
    lo, hi = p.domain
    a, b = dist.support()
    bad_low = a < lo or (p.open_low and a <= lo)
    bad_high = b > hi or (p.open_high and b >= hi)
    if bad_low or bad_high:
        reason = (f"draws can leave the domain {'(' if p.open_low else '['}{format_value(lo)}, "
                  f"{format_value(hi)}{')' if p.open_high else ']'}")
        if dist.kind == "normal":
            reason += " (give low/high to clip a normal distribution)"
        raise _err(source, key, reason, show)


def config_from_dict(d: dict, source: str = "<dict>") -> DatasetConfig:
    """Validate a config mapping (as read from TOML) into a :class:`DatasetConfig`.

    Parameters
    ----------
    d : dict
        The parsed TOML document.
    source : str
        Name used in error messages (the file path).

    Returns
    -------
    DatasetConfig

    Raises
    ------
    DatasetConfigError
        Unknown key or family, negative count, impossible range, value outside a parameter's
        domain, wrong type; the message names ``source``, the key and the value.
    """
    if not isinstance(d, dict):
        raise _err(source, "<root>", "a config must be a table", d)
    top = validated(_File, d, DatasetConfigError, source)
    iso = top.isovalues
    if len(set(iso)) != len(iso):
        raise _err(source, "isovalues", "isovalues must be distinct", d["isovalues"])
    names = tuple(n for n, _ in DEFAULT_SPLITS)
    splits = tuple((n, float(getattr(top.splits, n))) for n in names)
    if abs(sum(f for _, f in splits) - 1.0) > 1e-9:
        raise _err(source, "splits", "fractions must sum to 1", d["splits"])
    ae = d.get("auto_exposure", {"percentile": DEFAULT_AUTO_EXPOSURE[0], "level": DEFAULT_AUTO_EXPOSURE[1]})
    exposure = None if ae is False else validated(_Exposure, ae, DatasetConfigError, source, "auto_exposure")
    auto_exposure = None if exposure is None else (exposure.percentile, exposure.level)

    fam = d.get("families")
    if not isinstance(fam, dict) or not fam:
        raise _err(source, "families", "must be a table of family = weight (families: "
                   + ", ".join(FAMILIES) + ")", fam)
    weights: dict[str, float] = {}
    for name, w in fam.items():
        if name not in FAMILIES:
            raise _err(source, f"families.{name}", "unknown family (known: " + ", ".join(FAMILIES) + ")", name)
        weights[name] = validated(_Weight, w, DatasetConfigError, source, f"families.{name}")
    if sum(weights.values()) <= 0:
        raise _err(source, "families", "at least one family needs a positive weight", fam)
    families = tuple((f, weights[f]) for f in FAMILIES if weights.get(f, 0) > 0)

    def dist_of(p: ParamDef, value, where: str) -> Dist:
        dist = _parse_dist(value, where, source)
        _check_domain(p, dist, where, source)
        return dist

    common: dict[str, Dist] = {}
    per_family: dict[str, dict[str, Dist]] = {}
    for key, value in top.params.items():
        if key in FAMILIES:
            if not isinstance(value, dict):
                raise _err(source, f"params.{key}", "must be a table of parameter distributions", value)
            per_family[key] = {}
            for pk, pv in value.items():
                where = f"params.{key}.{pk}"
                p = _PARAM_BY_NAME.get(pk)
                if p is None:
                    raise _err(source, where, "unknown parameter (known: " + ", ".join(_PARAM_BY_NAME) + ")", pv)
                if key not in p.families:
                    raise _err(source, where, f"parameter not used by family {key} (used by: "
                               + ", ".join(p.families) + ")", pv)
                per_family[key][pk] = dist_of(p, pv, where)
            continue
        if key not in _PARAM_BY_NAME:
            raise _err(source, f"params.{key}", "unknown parameter or family (parameters: "
                       + ", ".join(_PARAM_BY_NAME) + "; families: " + ", ".join(FAMILIES) + ")", value)
        common[key] = dist_of(_PARAM_BY_NAME[key], value, f"params.{key}")

    resolved = {f: {p.name: per_family.get(f, {}).get(p.name) or common.get(p.name) or p.default_for(f)
                    for p in PARAMS if f in p.families} for f, _ in families}
    return DatasetConfig(count=top.count, seed=top.seed, shard_size=top.shard_size, isovalues=tuple(iso),
                         variant=top.variant, compress=top.compress, families=families, params=resolved,
                         source=source, raw=jsonable(d, default=str), splits=splits,
                         auto_exposure=auto_exposure)


def load_config(path) -> DatasetConfig:
    """Read and validate a dataset config TOML file.

    Parameters
    ----------
    path : str or Path
        The TOML file.

    Returns
    -------
    DatasetConfig

    Raises
    ------
    DatasetConfigError
        Missing file, TOML syntax error, or any validation failure (naming the file and key).
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DatasetConfigError(f"{path}: cannot read the config: {exc.strerror or exc}") from exc
    return config_from_dict(parse_toml(data, path, DatasetConfigError), source=str(path))
