"""Sweep files: a suite of parameter sweeps declared in TOML, expanded to cases.

A suite file (``scenes/suites/<name>.toml``) reads::
    [suite]
    name = "paper-figure3"          # default: the file stem
    description = "..."
    protocol = "paper"              # default protocol of the sweeps: "paper" or "rendered"
    scene = "plane_58deg"           # rendered: default base scene (bundled name or path)
    realisations = 1000             # per case
    seed = 0                        # root seed
    estimators = ["paper_oracle", "cone_axis"]   # optional subset (default: all)

    [base]                          # parameters shared by every sweep (see below)
    sigma = 0.05

    [[sweep]]
    name = "noise"                  # unique within the suite
    parameter = "sigma"             # the parameter varied ...
    values = [0.0, 0.02, 0.05]      # ... over these values (one case each)
    label = "noise sigma"           # axis label (default: the parameter)
    display_scale = 100.0           # factor for plots and tables (e.g. fraction -> %)
    set = { n = 100 }               # fixed parameters of this sweep only
    # or, instead of parameter/values:  cases = [{ x = 1, set = { ... } }, ...]

    [sweep.paper]                   # optional: the paper's stated figure for this sweep
    claim = "mean error below 1.25 deg throughout"
    check = "max_mean_below"        # see simtest.harness.claims.PAPER_CHECKS
    value = 1.25
    note = "why ours differs"

Parameters. ``paper`` protocol: the fields of :class:`simtest.simulate.paper.PaperParams`.
``rendered`` protocol: dotted scene keys (``"material.n"``, ``"geometry.tilt_deg"``, ...) applied
with :func:`simtest.scene.with_overrides`, and the derived key ``"radius_over_distance"`` (sphere or
cylinder of radius ``r d`` whose nearest point is at ``distance_mm`` d on the optical axis), and
the mesh poses ``colon_station`` (camera on the bundled colon's centre line at that fraction of its
length, looking ``mesh_view_deg`` off the tangent) and ``liver_azimuth_deg`` (camera
``mesh_distance_mm`` outside the bundled liver's bounding sphere at that azimuth and
``liver_elevation_deg``, aimed at its centre), which replace the scene's geometry. Both:
the reconstruction settings ``isovalue`` (t in (0, 1)) and ``joint_isovalues`` (list, for the
nested-isophote joint cone axis); rendered also ``image`` ("sensor" or "linear"),
``match_px`` (max distance from a true BP to a detected one), ``distance_mm`` and ``texture``
("scene", or "per_realisation": a procedural tissue's texture drawn for each realisation,
:class:`SceneSetting`).

Seeds: realisation ``i`` of a case draws from
``SeedSequence([root_seed, stable_hash(case.key), i])`` (:func:`realisation_seed`), so results do
not depend on how realisations are shared between workers; its first word is the render seed, its
second the texture seed where one is drawn
(:func:`simtest.harness.protocols.realisation_overrides`).

Errors: :class:`SuiteError` (a ValueError) with the message ``"<file>: <key>: <reason>"``.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from simtest._checks import keyed_error
from simtest._io import jsonable
from simtest.harness.claims import PAPER_CHECKS
from simtest.reconstruct import registry
from simtest.reconstruct.settings import ReconSettings
from simtest.resources import bundled
from simtest.scene import SceneError, bundled_scene_path, load_scene, with_overrides
from simtest.simulate.paper import PaperParams

__all__ = [
    "SuiteError",
    "Case",
    "Sweep",
    "Suite",
    "PROTOCOLS",
    "ESTIMATOR_NAMES",
    "RECON_KEYS",
    "load_suite",
    "suite_from_dict",
    "suites_dir",
    "bundled_suite_names",
    "resolve_suite_path",
    "stable_hash",
    "realisation_seed",
    "Scoring",
    "MeshPose",
    "SceneSetting",
    "harness_recon_settings",
    "MAX_TOTAL_REALISATIONS",
]

PROTOCOLS = ("paper", "rendered")

#: The estimators a suite that lists none scores side by side (:mod:`simtest.reconstruct.registry`).
ESTIMATOR_NAMES = tuple(name for name in registry.names() if registry.get(name).default)
#: Estimators that use the scope's light rig (:mod:`simtest.reconstruct.recommend`); a suite lists
#: them explicitly (``recommended`` is the normal that ``estimates.json`` recommends).
LIGHT_AWARE_NAMES = registry.names("light_aware", "recommendation", "oracle_input")

#: Most realisations one run may hold, over its distinct settings (a setting shared by several
#: sweeps runs once). Why: every realisation keeps its scored rows (an error, a cause and the
#: diagnostics per estimator: about 2 KB in Python objects, measured 1.4 KB for the rows alone with
#: six estimators) until the report is written, so the cap bounds a run at about 2 GB of memory; it
#: is 19 times the largest bundled suite (paper-figure3, 53 200 realisations), and at the paper
#: protocol's few hundred realisations per second and core it is already hours of work. A suite
#: file or ``-n`` beyond it is refused before anything is allocated.
MAX_TOTAL_REALISATIONS = 1_000_000

#: Reconstruction settings, valid in both protocols, with their defaults.
RECON_KEYS: dict[str, Any] = {
    "isovalue": 0.1,
    "joint_isovalues": [0.1, 0.2, 0.3, 0.4, 0.5],
}

#: Keys of :class:`MeshPose` among :data:`RENDERED_KEYS`.
_MESH_POSE_KEYS = ("colon_station", "liver_azimuth_deg", "mesh_view_deg", "mesh_distance_mm",
                   "liver_elevation_deg")

#: Extra keys of the rendered protocol, with their defaults.
RENDERED_KEYS: dict[str, Any] = {
    "image": "sensor",
    "match_px": 15.0,
    "radius_over_distance": None,
    "distance_mm": None,
    "colon_station": None,
    "liver_azimuth_deg": None,
    "mesh_view_deg": 30.0,
    "mesh_distance_mm": 40.0,
    "liver_elevation_deg": 20.0,
    "texture": "scene",
}
#: Values of the rendered key ``texture``: the scene's tissue texture in every realisation, or a
#: texture drawn for each (:class:`SceneSetting`).
TEXTURES = ("scene", "per_realisation")

_SUITE_KEYS = {"name", "description", "protocol", "scene", "realisations", "seed", "estimators"}
_SWEEP_KEYS = {"name", "parameter", "values", "label", "display_scale", "set", "cases", "paper",
               "protocol", "scene", "realisations", "description"}
_CASE_KEYS = {"x", "set", "label"}
_PAPER_KEYS = {"claim", "check", "value", "note", "estimator", "range", "source"}


class SuiteError(ValueError):
    """A suite file is invalid. The message reads ``"<file>: <key>: <reason>"``."""


#: ``_err(source, key, reason)``: the one-line error of a bad key (:func:`simtest._checks.keyed_error`).
_err = functools.partial(keyed_error, SuiteError)


def suites_dir() -> Path:
    """Folder of the bundled suites, ``scenes/suites``.

    Returns
    -------
    Path
        The folder (:func:`simtest.resources.bundled`: a clone's or an installed wheel's).
    """
    return bundled("scenes", "suites")


def bundled_suite_names() -> list[str]:
    """Names (file stems) of the bundled suites, sorted.

    Returns
    -------
    list of str
        E.g. ``["default", "nightly", "quick", ...]``; empty if the folder is missing.
    """
    return sorted(p.stem for p in suites_dir().glob("*.toml"))


def resolve_suite_path(name_or_path: str | Path) -> Path:
    """A bundled suite name (``"quick"``) or a path to a TOML file -> the file path.

    Parameters
    ----------
    name_or_path : str or Path
        An existing file, or the stem (with or without ``.toml``) of a suite in :func:`suites_dir`.

    Returns
    -------
    Path
        The suite file.

    Raises
    ------
    SuiteError
        If neither a file nor a bundled suite of that name exists (lists the bundled names).
    """
    p = Path(name_or_path)
    if p.is_file():
        return p
    stem = p.name[:-5] if p.name.endswith(".toml") else p.name
    q = suites_dir() / f"{stem}.toml"
    if q.is_file() and (p.parent == Path(".") or not p.suffix):
        return q
    raise SuiteError(f"{name_or_path}: suite: no such file and no bundled suite of that name "
                     f"(bundled: {', '.join(bundled_suite_names()) or 'none'})")


def stable_hash(key: str) -> int:
    """A 64-bit integer from a string, stable across processes and machines (SHA-256).

    Python's ``hash()`` is salted per process, so it cannot seed anything reproducible.

    Parameters
    ----------
    key : str
        Any string (UTF-8 encoded).

    Returns
    -------
    int
        The first 8 bytes of its SHA-256, little-endian, in [0, 2**64).
    """
    return int.from_bytes(hashlib.sha256(key.encode("utf-8")).digest()[:8], "little")


def realisation_seed(root_seed: int, case_key: str, index: int) -> np.random.SeedSequence:
    """The seed of realisation ``index`` of a case.

    Parameters
    ----------
    root_seed : int
        Suite root seed (0 is valid).
    case_key : str
        :attr:`Case.key`.
    index : int
        Realisation index.

    Returns
    -------
    numpy.random.SeedSequence
        ``SeedSequence([root_seed, stable_hash(case_key), index])``: independent of worker count
        and of the suite the case appears in.
    """
    return np.random.SeedSequence([int(root_seed), stable_hash(case_key), int(index)])


@dataclass(frozen=True)
class Scoring:
    """How a ``rendered`` realisation is scored (the case keys ``image`` and ``match_px``).

    Attributes
    ----------
    image : {"sensor", "linear"}
        The image reconstructed: the 8-bit sensor image, or the linear render (its grey).
    match_px : float
        A true highlight is matched to the nearest detected BP within this distance, px.
    """

    image: str = RENDERED_KEYS["image"]
    match_px: float = RENDERED_KEYS["match_px"]


@dataclass(frozen=True)
class MeshPose:
    """Where a ``rendered`` case places its camera on a bundled mesh (the case's mesh-pose keys).

    The colon is used when ``colon_station`` is set, the liver when ``liver_azimuth_deg`` is;
    neither: the scene's own camera (:func:`simtest.harness.protocols.mesh_pose_overrides`).

    Attributes
    ----------
    colon_station : float or None
        Fraction of the colon's centre line, in [0, 1].
    liver_azimuth_deg : float or None
        Azimuth of the camera about the liver, degrees.
    mesh_view_deg : float
        Colon: angle of the view off the centre line's tangent, degrees.
    mesh_distance_mm : float
        Liver: distance outside its bounding sphere, mm.
    liver_elevation_deg : float
        Liver: elevation of the camera, degrees.
    """

    colon_station: float | None = RENDERED_KEYS["colon_station"]
    liver_azimuth_deg: float | None = RENDERED_KEYS["liver_azimuth_deg"]
    mesh_view_deg: float = RENDERED_KEYS["mesh_view_deg"]
    mesh_distance_mm: float = RENDERED_KEYS["mesh_distance_mm"]
    liver_elevation_deg: float = RENDERED_KEYS["liver_elevation_deg"]

    @property
    def on_mesh(self) -> bool:
        """Whether the case places its camera on a bundled mesh."""
        return self.colon_station is not None or self.liver_azimuth_deg is not None


@dataclass(frozen=True)
class SceneSetting:
    """What a ``rendered`` case changes in its base scene.

    Attributes
    ----------
    overrides : dict
        Dotted scene overrides as the suite gives them (``"material.n"``, ...), sorted by key.
    radius_over_distance : float or None
        Sphere or cylinder: its radius as a fraction of ``distance_mm``; the surface is then placed
        ``distance_mm`` in front of the camera (:meth:`scene_overrides`).
    distance_mm : float or None
        Camera to the nearest surface point along the optical axis, mm (with
        ``radius_over_distance``).
    mesh : MeshPose
        The camera's place on a bundled mesh, if any.
    texture : {"scene", "per_realisation"}
        The procedural tissue's texture (albedo, vessels, micro-relief, film): the scene's
        ``material.texture_seed`` in every realisation (``"scene"``, the default), or one drawn for
        each realisation from its seed (``"per_realisation"``,
        :class:`~simtest.harness.protocols.RenderedRunner`), so that a case's realisations sample
        the tissue as well as the sensor's noise, and its statistics are not those of one
        texture's accidents.
    """

    overrides: dict
    radius_over_distance: float | None = None
    distance_mm: float | None = None
    mesh: MeshPose = field(default_factory=MeshPose)
    texture: str = RENDERED_KEYS["texture"]

    def scene_overrides(self, mesh_pose: Callable[[MeshPose], dict] | None = None) -> dict:
        """Every dotted override of the base scene, in the order they apply.

        Parameters
        ----------
        mesh_pose : callable, optional
            ``MeshPose -> overrides`` placing the camera on the mesh
            (:func:`simtest.harness.protocols.mesh_pose_overrides`); called only when the case
            is on a mesh.

        Returns
        -------
        dict
            :attr:`overrides`, then ``geometry.radius_mm = r`` and ``geometry.center_mm = [0, 0,
            d + r]`` (``r = radius_over_distance x distance_mm``) when set, then the mesh pose's.
        """
        over = dict(self.overrides)
        if self.radius_over_distance is not None:
            r = self.radius_over_distance * self.distance_mm
            over["geometry.radius_mm"] = r
            over["geometry.center_mm"] = [0.0, 0.0, self.distance_mm + r]
        if self.mesh.on_mesh and mesh_pose is not None:
            over.update(mesh_pose(self.mesh))
        return over


def harness_recon_settings(protocol: str, isovalue: float, joint_isovalues) -> ReconSettings:
    """The reconstruction settings of a harness case (the paper's, as the committed reports used).

    Parameters
    ----------
    protocol : {"paper", "rendered"}
        ``paper``: the known highlight of an image normalised to 1 at the BP (``reconstruct_roi``),
        t relative to a full scale of 1, no smoothing. ``rendered``: every highlight detected at
        0.7 of the full scale (``reconstruct``; the runner sets the full scale to each image's
        maximum), t relative to the BP, no smoothing.
    isovalue : float
        The primary isovalue t.
    joint_isovalues : iterable of float
        Further nested isovalues for the joint cone axis (a repeat of t is dropped).

    Returns
    -------
    ReconSettings
        ``isovalues = (t, *others)``.

    Raises
    ------
    ValueError
        If the isovalues are invalid (:class:`~simtest.reconstruct.settings.ReconSettings`).
    """
    t = float(isovalue)
    isovalues = (t,) + tuple(float(v) for v in joint_isovalues if float(v) != t)
    if protocol == "paper":
        return ReconSettings(isovalues=isovalues, normalise="full_scale", full_scale=1.0,
                             smooth_sigma_px=0.0)
    return ReconSettings(isovalues=isovalues, normalise="bp", smooth_sigma_px=0.0,
                         detection="full_scale")


@dataclass(frozen=True)
class Case:
    """One parameter setting of a sweep, run ``realisations`` times.

    Attributes
    ----------
    key : str
        Stable identity of the setting (protocol, scene and resolved parameters as canonical JSON);
        it seeds the realisations, so the same setting gets the same numbers in any suite.
    id : str
        ``<sweep>@<x>``: unique in the suite (a setting shared by two sweeps has one key, two ids).
    suite, sweep : str
        Names of the suite and sweep that hold it.
    protocol : {"paper", "rendered"}
        How a realisation is produced (:mod:`simtest.harness.protocols`).
    scene : str or None
        Rendered: the base scene file (absolute path) it is built from.
    scene_name : str or None
        Rendered: the scene's name as written in the suite (bundled name or file name).
    params : dict
        Resolved parameters: for ``paper`` every PaperParams field plus the reconstruction keys;
        for ``rendered`` the scene overrides (dotted keys) plus the rendered and reconstruction keys.
    x : float
        The swept value (for plots), before ``display_scale``.
    realisations : int
        Number of realisations (independent seeds) of the case.
    recon : ReconSettings
        The reconstruction settings (:func:`harness_recon_settings`), made and validated once.
    paper : PaperParams or None
        ``paper``: the protocol's parameters; None for ``rendered``.
    scene_setting : SceneSetting or None
        ``rendered``: the changes to the base scene; None for ``paper``.
    scoring : Scoring or None
        ``rendered``: how a realisation is scored; None for ``paper``.

    Notes
    -----
    ``params`` is the case as written (one flat table, the source of ``key`` and of the reports'
    ``params``); the runners read the typed fields.
    """

    key: str
    id: str
    suite: str
    sweep: str
    protocol: str
    scene: str | None
    scene_name: str | None
    params: dict
    x: float
    realisations: int
    recon: ReconSettings
    paper: PaperParams | None = None
    scene_setting: SceneSetting | None = None
    scoring: Scoring | None = None

    def to_dict(self) -> dict:
        """JSON-able dict of the case (without the absolute scene path)."""
        return {"id": self.id, "key": self.key, "sweep": self.sweep, "protocol": self.protocol,
                "scene": self.scene_name, "params": self.params, "x": self.x,
                "realisations": self.realisations}


@dataclass(frozen=True)
class Sweep:
    """A named list of cases varying one parameter (or an explicit list of settings).

    Attributes
    ----------
    name : str
        Sweep name, unique in the suite.
    protocol : {"paper", "rendered"}
        Protocol of its cases.
    parameter : str
        The swept parameter (a PaperParams field, a dotted scene key or a reconstruction key).
    label : str
        Axis label for plots (with its unit).
    display_scale : float
        Factor applied to ``Case.x`` in plots and tables.
    cases : tuple of Case
        The expanded settings, in file order.
    paper : dict or None
        The paper claim this sweep checks (``claim``, ``check``, ``value``, ...), if any.
    description : str
        Free text.
    """

    name: str
    protocol: str
    parameter: str
    label: str
    display_scale: float
    cases: tuple[Case, ...]
    paper: dict | None = None
    description: str = ""


@dataclass(frozen=True)
class Suite:
    """A loaded, validated suite: sweeps already expanded to cases.

    Attributes
    ----------
    name, description : str
        From the ``[suite]`` table.
    source : str
        The file it was read from (for messages).
    seed : int
        Root seed of every realisation (0 is valid).
    realisations : int
        Default realisations per case.
    estimators : tuple of str
        Keys of :data:`simtest.harness.estimators.ESTIMATORS` scored.
    sweeps : tuple of Sweep
        In file order.
    sha256 : str
        sha256 of the suite file's bytes (empty for a suite built from a dict).
    raw : dict
        The document as read, used by :meth:`with_overrides`.
    external : tuple of (str, str)
        External estimators ``(name, "package.module:function")`` scored beside the built-in
        ones (:mod:`simtest.harness.external`); their names end :attr:`estimators`.
    """

    name: str
    description: str
    source: str
    seed: int
    realisations: int
    estimators: tuple[str, ...]
    sweeps: tuple[Sweep, ...]
    sha256: str = ""
    raw: dict = field(default_factory=dict, compare=False, repr=False)
    external: tuple[tuple[str, str], ...] = ()

    @property
    def cases(self) -> list[Case]:
        """All cases, sweep by sweep, in file order."""
        return [c for s in self.sweeps for c in s.cases]

    @property
    def distinct_cases(self) -> list[Case]:
        """The cases that run: one per distinct setting (``(key, realisations)``), first seen.

        A setting shared by several sweeps (the default point of two sweeps, say) is one case of
        each sweep in the reports but runs once; the runner, the progress bar, the console
        header and the report count these.
        """
        return list({(c.key, c.realisations): c for c in self.cases}.values())

    @property
    def total_realisations(self) -> int:
        """Realisations that run: over :attr:`distinct_cases` (a shared setting counts once)."""
        return sum(c.realisations for c in self.distinct_cases)

    def with_overrides(self, *, seed: int | None = None,
                       realisations: int | None = None) -> Suite:
        """A copy with another root seed and/or number of realisations per case.

        Parameters
        ----------
        seed : int, optional
            New root seed (0 is valid); None keeps the suite's.
        realisations : int, optional
            Realisations of every case (per-sweep values are dropped); None keeps them.

        Returns
        -------
        Suite
            Re-validated from the raw document, with the same source and sha256.

        Raises
        ------
        SuiteError
            If a new value is invalid.
        """
        d = dict(self.raw)
        d["suite"] = dict(d.get("suite", {}))
        if seed is not None:
            d["suite"]["seed"] = seed
        if realisations is not None:
            d["suite"]["realisations"] = realisations
            d["sweep"] = [{k: v for k, v in s.items() if k != "realisations"}
                          for s in d.get("sweep", [])]
        new = suite_from_dict(d, source=self.source, sha256=self.sha256)
        if not self.external:
            return new
        return dataclasses.replace(new, estimators=new.estimators + tuple(n for n, _ in self.external),
                                   external=self.external)


def load_suite(name_or_path: str | Path) -> Suite:
    """Load and validate a suite file (bundled name or path).

    Parameters
    ----------
    name_or_path : str or Path
        Bundled suite name (``"quick"``) or a TOML file.

    Returns
    -------
    Suite
        Sweeps expanded to cases; ``sha256`` is that of the file's bytes.

    Raises
    ------
    SuiteError
        Unknown key, wrong type, bad value, unknown parameter or scene: ``"<file>: <key>: <why>"``.
    """
    path = resolve_suite_path(name_or_path)
    data = path.read_bytes()
    try:
        raw = tomllib.loads(data.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise SuiteError(f"{path}: not valid TOML: {e}") from None
    return suite_from_dict(raw, source=str(path), sha256=hashlib.sha256(data).hexdigest())


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_keys(d: Mapping, allowed: set, source: str, where: str) -> None:
    if not isinstance(d, Mapping):
        raise _err(source, where, f"expected a table, got {type(d).__name__}")
    for k in d:
        if k not in allowed:
            raise _err(source, f"{where}.{k}" if where else k,
                       f"unknown key (allowed: {', '.join(sorted(allowed))})")


def _check_recon(key: str, value, source: str, where: str) -> Any:
    if key == "isovalue":
        if not _is_num(value) or not 0 < value < 1:
            raise _err(source, where, f"isovalue must be a number in (0, 1), got {value!r}")
        return float(value)
    if key == "joint_isovalues":
        if (not isinstance(value, (list, tuple)) or len(value) < 2
                or not all(_is_num(v) and 0 < v < 1 for v in value)):
            raise _err(source, where, "joint_isovalues must be a list of at least 2 numbers in "
                                      f"(0, 1), got {value!r}")
        return [float(v) for v in value]
    if key == "image":
        if value not in ("sensor", "linear"):
            raise _err(source, where, f"image must be 'sensor' or 'linear', got {value!r}")
        return value
    if key == "texture":
        if value not in TEXTURES:
            raise _err(source, where, f"texture must be one of {', '.join(map(repr, TEXTURES))}, "
                                      f"got {value!r}")
        return value
    if key in ("match_px", "radius_over_distance", "distance_mm", "mesh_distance_mm"):
        if value is not None and (not _is_num(value) or value <= 0):
            raise _err(source, where, f"{key} must be a number > 0, got {value!r}")
        return None if value is None else float(value)
    ranges = {"colon_station": (0.0, 1.0), "liver_azimuth_deg": (-360.0, 360.0),
              "mesh_view_deg": (0.0, 89.0), "liver_elevation_deg": (-89.0, 89.0)}
    if key in ranges:
        lo, hi = ranges[key]
        if value is not None and (not _is_num(value) or not lo <= value <= hi):
            raise _err(source, where, f"{key} must be a number in [{lo:g}, {hi:g}], got {value!r}")
        return None if value is None else float(value)
    raise AssertionError(key)


def _resolve_paper(params: Mapping, source: str, where: str) -> dict:
    names = set(PaperParams.field_names())
    sim, out = {}, {}
    for k, v in params.items():
        if k in RECON_KEYS:
            out[k] = _check_recon(k, v, source, f"{where}.{k}")
        elif k in names:
            sim[k] = v
        else:
            raise _err(source, f"{where}.{k}", "unknown parameter of the paper protocol (known: "
                       f"{', '.join(sorted(names | set(RECON_KEYS)))})")
    # Types as PaperParams wants them (TOML ints for float fields are fine; floats for ints are not).
    fields = {f.name: f for f in dataclasses.fields(PaperParams)}
    for k, v in list(sim.items()):
        if fields[k].type in ("float", "float | None") and _is_num(v):
            sim[k] = float(v)
    try:
        pp = PaperParams(**sim)
    except (ValueError, TypeError) as e:
        bad = next((k for k in sim if f"PaperParams.{k}:" in str(e)), "?")
        raise _err(source, f"{where}.{bad}", str(e).split(": ", 1)[-1]) from None
    resolved = dataclasses.asdict(pp)
    for k, d in RECON_KEYS.items():
        resolved[k] = out.get(k, d)
    return resolved


def _resolve_rendered(scene_path: Path, params: Mapping, source: str, where: str) -> dict:
    overrides, out = {}, {}
    for k, v in params.items():
        if k in RECON_KEYS or k in RENDERED_KEYS:
            out[k] = _check_recon(k, v, source, f"{where}.{k}")
        elif "." in k:
            overrides[k] = v
        else:
            raise _err(source, f"{where}.{k}", "unknown parameter of the rendered protocol "
                       "(expected a dotted scene key such as 'material.n', or one of "
                       f"{', '.join(sorted(set(RECON_KEYS) | set(RENDERED_KEYS)))})")
    try:
        spec = load_scene(scene_path)
        spec = with_overrides(spec, overrides)
    except SceneError as e:
        raise _err(source, where, f"scene override rejected: {e}") from None
    rod = out.get("radius_over_distance")
    if rod is not None:
        if spec.geometry.type not in ("sphere", "cylinder"):
            raise _err(source, f"{where}.radius_over_distance",
                       f"needs a sphere or cylinder scene, got geometry.type = "
                       f"{spec.geometry.type!r}")
        if out.get("distance_mm") is None:
            raise _err(source, f"{where}.distance_mm", "radius_over_distance needs distance_mm")
    if out.get("texture", "scene") != "scene" and spec.material.model != "tissue":
        raise _err(source, f"{where}.texture", f"needs a procedural tissue (material.model = "
                                               f"\"tissue\"), got {spec.material.model!r}")
    resolved = {k: jsonable(v) for k, v in sorted(overrides.items())}
    for k, d in {**RECON_KEYS, **RENDERED_KEYS}.items():
        resolved[k] = out.get(k, d)
    if resolved["texture"] == RENDERED_KEYS["texture"]:
        # the default is left out of the case's key: the cases of suites that do not name it keep
        # their keys, and so their realisations' seeds
        del resolved["texture"]
    return resolved


def _resolve_scene(name, source: str, where: str) -> Path:
    if not isinstance(name, str) or not name:
        raise _err(source, where, f"expected a bundled scene name or a path, got {name!r}")
    p = Path(name)
    if not p.is_absolute() and source not in ("<dict>", ""):
        q = Path(source).resolve().parent / p
        if q.is_file():
            return q
    if p.is_file():
        return p.resolve()
    try:
        return bundled_scene_path(name)
    except KeyError as e:
        raise _err(source, where, str(e).strip("'\"")) from None


def _typed(protocol: str, params: Mapping, source: str, where: str) -> dict:
    """The typed fields of a case (:class:`Case`) from its resolved flat ``params``."""
    try:
        recon = harness_recon_settings(protocol, params["isovalue"], params["joint_isovalues"])
    except ValueError as e:
        raise _err(source, f"{where}.joint_isovalues", str(e)) from None
    if protocol == "paper":
        return {"recon": recon, "paper": PaperParams(**{k: v for k, v in params.items()
                                                         if k not in RECON_KEYS})}
    mesh = MeshPose(**{k: params[k] for k in _MESH_POSE_KEYS})
    setting = SceneSetting(overrides={k: v for k, v in params.items() if "." in k},
                           radius_over_distance=params["radius_over_distance"],
                           distance_mm=params["distance_mm"], mesh=mesh,
                           texture=params.get("texture", RENDERED_KEYS["texture"]))
    return {"recon": recon, "scene_setting": setting,
            "scoring": Scoring(image=params["image"], match_px=float(params["match_px"]))}


def _case_key(protocol: str, scene_name: str | None, params: Mapping) -> str:
    return f"{protocol}|{scene_name or '-'}|" + json.dumps(params, sort_keys=True,
                                                           separators=(",", ":"))


def suite_from_dict(raw: Mapping[str, Any], source: str = "<dict>", sha256: str = "") -> Suite:
    """Validate a suite given as a dict (the TOML layout) and expand it to cases.

    Parameters
    ----------
    raw : mapping
        ``{"suite": {...}, "base": {...}, "sweep": [{...}, ...]}``.
    source : str
        File name for messages.
    sha256 : str
        Digest of the file, recorded in reports.

    Returns
    -------
    Suite

    Raises
    ------
    SuiteError
    """
    _check_keys(raw, {"suite", "base", "sweep", "tolerances"}, source, "")
    head = raw.get("suite", {})
    _check_keys(head, _SUITE_KEYS, source, "suite")
    default_name = Path(source).stem if source not in ("<dict>", "") else "suite"
    name = head.get("name", default_name)
    if not isinstance(name, str) or not name or any(c in name for c in "/\\ "):
        raise _err(source, "suite.name", f"expected a name without spaces or slashes, got {name!r}")
    description = head.get("description", "")
    if not isinstance(description, str):
        raise _err(source, "suite.description", "expected a string")
    protocol = head.get("protocol", "paper")
    if protocol not in PROTOCOLS:
        raise _err(source, "suite.protocol", f"expected one of {PROTOCOLS}, got {protocol!r}")
    realisations = head.get("realisations", 100)
    if isinstance(realisations, bool) or not isinstance(realisations, int) or realisations < 1:
        raise _err(source, "suite.realisations", f"expected an integer >= 1, got {realisations!r}")
    seed = head.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise _err(source, "suite.seed", f"expected an integer >= 0, got {seed!r}")
    estimators = head.get("estimators", list(ESTIMATOR_NAMES))
    if (not isinstance(estimators, list) or not estimators
            or any(e not in registry.names() for e in estimators)):
        raise _err(source, "suite.estimators",
                   f"expected a non-empty list from {registry.names()}, "
                   f"got {estimators!r}")
    base = raw.get("base", {})
    _check_keys(base, set(base) if isinstance(base, Mapping) else set(), source, "base")
    if "scene" in head:
        _resolve_scene(head["scene"], source, "suite.scene")
    sweeps_raw = raw.get("sweep", [])
    if not isinstance(sweeps_raw, list) or not sweeps_raw:
        raise _err(source, "sweep", "expected at least one [[sweep]] table")

    sweeps: list[Sweep] = []
    seen: set[str] = set()
    for i, sw in enumerate(sweeps_raw):
        where = f"sweep[{i}]"
        _check_keys(sw, _SWEEP_KEYS, source, where)
        sname = sw.get("name")
        if not isinstance(sname, str) or not sname:
            raise _err(source, f"{where}.name", "every sweep needs a name")
        where = f"sweep.{sname}"
        if sname in seen:
            raise _err(source, f"{where}.name", "duplicate sweep name")
        seen.add(sname)
        sproto = sw.get("protocol", protocol)
        if sproto not in PROTOCOLS:
            raise _err(source, f"{where}.protocol", f"expected one of {PROTOCOLS}, got {sproto!r}")
        sreal = sw.get("realisations", realisations)
        if isinstance(sreal, bool) or not isinstance(sreal, int) or sreal < 1:
            raise _err(source, f"{where}.realisations", f"expected an integer >= 1, got {sreal!r}")
        _check_bound(sreal, source, f"{where}.realisations" if "realisations" in sw
                     else "suite.realisations")
        scene_path, scene_name = None, None
        if sproto == "rendered":
            scene_name = sw.get("scene", head.get("scene"))
            if scene_name is None:
                raise _err(source, f"{where}.scene", "a rendered sweep needs a scene "
                                                     "(sweep.scene or suite.scene)")
            scene_path = _resolve_scene(scene_name, source, f"{where}.scene")
        elif "scene" in sw:
            raise _err(source, f"{where}.scene", "only rendered sweeps take a scene")
        fixed = sw.get("set", {})
        _check_keys(fixed, set(fixed) if isinstance(fixed, Mapping) else set(), source,
                    f"{where}.set")
        scale = sw.get("display_scale", 1.0)
        if not _is_num(scale) or scale == 0:
            raise _err(source, f"{where}.display_scale", f"expected a non-zero number, got {scale!r}")
        # settings: (x, overrides)
        if "cases" in sw:
            if "parameter" in sw or "values" in sw:
                raise _err(source, where, "give either parameter/values or cases, not both")
            parameter = "case"
            settings = []
            if not isinstance(sw["cases"], list) or not sw["cases"]:
                raise _err(source, f"{where}.cases", "expected a non-empty list of tables")
            for j, cs in enumerate(sw["cases"]):
                _check_keys(cs, _CASE_KEYS, source, f"{where}.cases[{j}]")
                x = cs.get("x", j)
                if not _is_num(x):
                    raise _err(source, f"{where}.cases[{j}].x", f"expected a number, got {x!r}")
                cset = cs.get("set", {})
                _check_keys(cset, set(cset) if isinstance(cset, Mapping) else set(), source,
                            f"{where}.cases[{j}].set")
                settings.append((float(x), dict(cset), f"{where}.cases[{j}].set"))
        else:
            parameter = sw.get("parameter")
            if not isinstance(parameter, str) or not parameter:
                raise _err(source, f"{where}.parameter", "expected a parameter name")
            values = sw.get("values")
            if not isinstance(values, list) or not values:
                raise _err(source, f"{where}.values", "expected a non-empty list of values")
            settings = []
            for j, v in enumerate(values):
                if not _is_num(v):
                    raise _err(source, f"{where}.values[{j}]", f"expected a number, got {v!r}")
                settings.append((float(v), {parameter: v}, f"{where}.values[{j}]"))
        label = sw.get("label", parameter)
        if not isinstance(label, str):
            raise _err(source, f"{where}.label", "expected a string")
        paper = sw.get("paper")
        if paper is not None:
            _check_keys(paper, _PAPER_KEYS, source, f"{where}.paper")
            chk = paper.get("check")
            chks = [chk] if isinstance(chk, str) or chk is None else chk
            vals = [paper.get("value")] if isinstance(chk, str) or chk is None else paper.get("value")
            if not isinstance(chks, list) or not isinstance(vals, list) or len(chks) != len(vals):
                raise _err(source, f"{where}.paper.value", "give one value per check (check and "
                                                           "value both lists, or both single)")
            for c_, v_ in zip(chks, vals):
                if c_ is None:
                    continue
                if c_ not in PAPER_CHECKS:
                    raise _err(source, f"{where}.paper.check",
                               f"unknown check {c_!r} (known: {', '.join(PAPER_CHECKS)})")
                two = c_ in ("slope_in_range", "argmin_in_range")
                if two and not (isinstance(v_, list) and len(v_) == 2 and all(map(_is_num, v_))):
                    raise _err(source, f"{where}.paper.value", f"check {c_} needs [low, high]")
                if not two and not _is_num(v_):
                    raise _err(source, f"{where}.paper.value", f"check {c_} needs a number")
            if paper.get("source", "paper") not in ("paper", "prediction"):
                raise _err(source, f"{where}.paper.source",
                           f"expected 'paper' or 'prediction', got {paper.get('source')!r}")
            est = paper.get("estimator", "paper_oracle")
            if est not in registry.names():
                raise _err(source, f"{where}.paper.estimator", f"unknown estimator {est!r}")
        cases = []
        xs = [x for x, _, _ in settings]
        if len(set(xs)) != len(xs):
            raise _err(source, f"{where}.values" if parameter != "case" else f"{where}.cases",
                       "duplicate values (each setting of a sweep needs its own x)")
        for x, over, cwhere in settings:
            merged = {**base, **fixed, **over}
            if sproto == "paper":
                params = _resolve_paper(merged, source, cwhere)
            else:
                params = _resolve_rendered(scene_path, merged, source, cwhere)
            key = _case_key(sproto, scene_name, params)
            cases.append(Case(key=key, id=f"{sname}@{x:g}", suite=name, sweep=sname, protocol=sproto,
                              scene=None if scene_path is None else str(scene_path),
                              scene_name=scene_name, params=params, x=x, realisations=sreal,
                              **_typed(sproto, params, source, cwhere)))
        sweeps.append(Sweep(name=sname, protocol=sproto, parameter=parameter, label=label,
                            display_scale=float(scale), cases=tuple(cases), paper=paper,
                            description=sw.get("description", "")))
    suite = Suite(name=name, description=description, source=source, seed=seed,
                  realisations=realisations, estimators=tuple(estimators), sweeps=tuple(sweeps),
                  sha256=sha256, raw=_deepcopy(raw))
    total = suite.total_realisations
    if total > MAX_TOTAL_REALISATIONS:
        raise _err(source, "realisations", f"{total:,} realisations over "
                   f"{len(suite.distinct_cases)} distinct settings exceed the maximum of "
                   f"{MAX_TOTAL_REALISATIONS:,} per run (about 2 KB of results each are held "
                   "until the report: split the suite or lower its realisations)")
    return suite


def _check_bound(n: int, source: str, where: str) -> None:
    """Refuse one case's realisations above :data:`MAX_TOTAL_REALISATIONS` before expanding."""
    if n > MAX_TOTAL_REALISATIONS:
        raise _err(source, where, f"{n:,} realisations exceed the maximum of "
                   f"{MAX_TOTAL_REALISATIONS:,} per run (about 2 KB of results each are held "
                   "until the report)")


def _deepcopy(d):
    if isinstance(d, Mapping):
        return {k: _deepcopy(v) for k, v in d.items()}
    if isinstance(d, list):
        return [_deepcopy(v) for v in d]
    return d
