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

Parameters: ``paper``: the fields of :class:`simtest.simulate.paper.PaperParams`; ``rendered``:
dotted scene keys (``"material.n"``, ...) and the keys of
:class:`~simtest.harness.cases.RenderedKeys`; both: those of
:class:`~simtest.harness.cases.ReconKeys`. Realisation ``i`` of a case draws from
:func:`realisation_seed`, independent of the workers. Errors: :class:`SuiteError` with the message
``"<file>: <key>: <reason>"``.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, Mapping

from pydantic import AfterValidator, Field
from pydantic.dataclasses import dataclass as pydantic_dataclass

from simtest._checks import keyed_error
from simtest._config import CONFIG, Int, Number, Str, parse_toml, validated
from simtest._io import jsonable
from simtest.harness.claims import PAPER_CHECKS
from simtest.harness.cases import (MESH_POSE_KEYS, RECON_KEYS, RENDERED_KEYS, Case,
                                   MeshPose, ReconKeys, RenderedKeys, SceneSetting, Scoring, Sweep,
                                   harness_recon_settings, realisation_seed, stable_hash)
from simtest.reconstruct import registry
from simtest.resources import bundled
from simtest.scene import SceneError, bundled_scene_path, load_scene, with_overrides
from simtest.simulate.paper import PaperParams

__all__ = ["SuiteError", "Case", "Sweep", "Suite", "ESTIMATOR_NAMES", "RECON_KEYS",
           "load_suite", "suite_from_dict", "suites_dir", "bundled_suite_names", "resolve_suite_path",
           "stable_hash", "realisation_seed", "Scoring", "MeshPose", "SceneSetting",
           "harness_recon_settings", "MAX_TOTAL_REALISATIONS"]

#: The estimators a suite that lists none scores side by side (:mod:`simtest.reconstruct.registry`).
ESTIMATOR_NAMES = tuple(name for name in registry.names() if registry.get(name).default)
#: Estimators that use the scope's light rig (:mod:`simtest.reconstruct.recommend`); a suite lists them.
LIGHT_AWARE_NAMES = registry.names("light_aware", "recommendation", "oracle_input")

#: Most realisations one run may hold, over its distinct settings: each keeps about 2 KB of scored
#: rows until the report is written, so the cap bounds a run at about 2 GB of memory.
MAX_TOTAL_REALISATIONS = 1_000_000


class SuiteError(ValueError):
    """A suite file is invalid. The message reads ``"<file>: <key>: <reason>"``."""


#: ``_err(source, key, reason)``: the one-line error of a bad key (:func:`simtest._checks.keyed_error`).
_err = functools.partial(keyed_error, SuiteError)
#: The suite file's tables: frozen pydantic dataclasses, unknown keys refused.
_model = functools.partial(pydantic_dataclass, frozen=True, config=CONFIG)
_Protocol = Literal["paper", "rendered"]


def _known_estimator(name: str) -> str:
    """An estimator name the registry knows when the suite is read."""
    if name not in registry.names():
        raise ValueError("must be one of " + ", ".join(repr(n) for n in registry.names()))
    return name


_Estimator = Annotated[Str, AfterValidator(_known_estimator)]


@_model
class _Head:
    """The ``[suite]`` table."""

    name: Str | None = None
    description: Str = ""
    protocol: _Protocol = "paper"
    scene: Str | None = None
    realisations: Int = Field(100, ge=1)
    seed: Int = Field(0, ge=0)
    estimators: list[_Estimator] = Field(default_factory=lambda: list(ESTIMATOR_NAMES), min_length=1)


@_model
class _Paper:
    """A sweep's ``[sweep.paper]`` table: the paper's figure it checks (:mod:`.claims`)."""

    claim: Any = None
    check: Any = None
    value: Any = None
    note: Any = None
    estimator: _Estimator = "paper_oracle"
    range: Any = None
    source: Literal["paper", "prediction"] = "paper"


@_model
class _CaseTable:
    """One entry of a sweep's ``cases``."""

    x: Number | None = None
    set: dict[str, Any] = Field(default_factory=dict)
    label: Any = None


def _non_zero(v):
    if v == 0:
        raise ValueError("expected a non-zero number")
    return v


@_model
class _SweepTable:
    """One ``[[sweep]]`` table."""

    name: Str = Field(min_length=1)
    protocol: _Protocol | None = None
    scene: Str | None = None
    realisations: Int | None = Field(None, ge=1)
    parameter: Str | None = Field(None, min_length=1)
    values: list[Number] | None = Field(None, min_length=1)
    cases: list[_CaseTable] | None = Field(None, min_length=1)
    label: Str | None = None
    display_scale: Annotated[Number, AfterValidator(_non_zero)] = 1.0
    set: dict[str, Any] = Field(default_factory=dict)
    paper: _Paper | None = None
    description: Str = ""


@_model
class _SuiteFile:
    """The whole document."""

    suite: dict[str, Any] = Field(default_factory=dict)
    base: dict[str, Any] = Field(default_factory=dict)
    sweep: list[dict[str, Any]] = Field(min_length=1)
    tolerances: Any = None


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
        Estimator names scored; external ones last.
    sweeps : tuple of Sweep
        In file order.
    sha256 : str
        sha256 of the suite file's bytes (empty for a suite built from a dict).
    raw : dict
        The document as read, used by :meth:`with_overrides`.
    external : tuple of (str, str)
        External estimators ``(name, "package.module:function")`` (:mod:`simtest.harness.external`).
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
        """The cases that run: one per distinct ``(key, realisations)``, first seen (a setting shared by
        several sweeps runs once).
        """
        return list({(c.key, c.realisations): c for c in self.cases}.values())

    @property
    def total_realisations(self) -> int:
        """Realisations that run, over :attr:`distinct_cases`."""
        return sum(c.realisations for c in self.distinct_cases)

    def with_overrides(self, *, seed: int | None = None, realisations: int | None = None) -> Suite:
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
            d["sweep"] = [{k: v for k, v in s.items() if k != "realisations"} for s in d.get("sweep", [])]
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
    raw = parse_toml(data, path, SuiteError)
    return suite_from_dict(raw, source=str(path), sha256=hashlib.sha256(data).hexdigest())


def _keyed(params: Mapping, cls: type, source: str, where: str, protocol: str, others: set) -> tuple[Any, dict]:
    """Split a case's ``params`` into ``cls``'s keys (validated) and the protocol's own
    (``others``, or dotted scene keys where ``others`` is empty); refuse any other key.
    """
    mine, rest = {}, {}
    for k, v in params.items():
        if k in cls.__dataclass_fields__:
            mine[k] = v
        elif k in others or (not others and "." in k):
            rest[k] = v
        else:
            known = (f"expected a dotted scene key such as 'material.n', or one of "
                     f"{', '.join(sorted(cls.__dataclass_fields__))}" if not others else
                     f"known: {', '.join(sorted(others | set(cls.__dataclass_fields__)))}")
            raise _err(source, f"{where}.{k}", f"unknown parameter of the {protocol} protocol ({known})")
    return validated(cls, mine, SuiteError, source, where), rest


def _resolve_paper(params: Mapping, source: str, where: str) -> dict:
    recon, sim = _keyed(params, ReconKeys, source, where, "paper", set(PaperParams.field_names()))
    pp = validated(PaperParams, sim, SuiteError, source, where)
    return {**dataclasses.asdict(pp), **dataclasses.asdict(recon)}


def _resolve_rendered(scene_path: Path, params: Mapping, source: str, where: str) -> dict:
    keys, overrides = _keyed(params, RenderedKeys, source, where, "rendered", set())
    try:
        spec = with_overrides(load_scene(scene_path), overrides)
    except SceneError as e:
        raise _err(source, where, f"scene override rejected: {e}") from None
    if keys.radius_over_distance is not None:
        if spec.geometry.type not in ("sphere", "cylinder"):
            raise _err(source, f"{where}.radius_over_distance",
                       f"needs a sphere or cylinder scene, got geometry.type = {spec.geometry.type!r}")
        if keys.distance_mm is None:
            raise _err(source, f"{where}.distance_mm", "radius_over_distance needs distance_mm")
    if keys.texture != "scene" and spec.material.model != "tissue":
        raise _err(source, f"{where}.texture", f"needs a procedural tissue (material.model = "
                                               f"\"tissue\"), got {spec.material.model!r}")
    resolved = {k: jsonable(v) for k, v in sorted(overrides.items())}
    resolved.update(dataclasses.asdict(keys))
    if resolved["texture"] == RENDERED_KEYS["texture"]:
        # the default is left out of the case's key, so that older cases keep their seeds
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
        return {"recon": recon, "paper": PaperParams(**{k: v for k, v in params.items() if k not in RECON_KEYS})}
    mesh = MeshPose(**{k: params[k] for k in MESH_POSE_KEYS})
    setting = SceneSetting(overrides={k: v for k, v in params.items() if "." in k},
                           radius_over_distance=params["radius_over_distance"],
                           distance_mm=params["distance_mm"], mesh=mesh,
                           texture=params.get("texture", RENDERED_KEYS["texture"]))
    return {"recon": recon, "scene_setting": setting,
            "scoring": Scoring(image=params["image"], match_px=float(params["match_px"]))}


def _case_key(protocol: str, scene_name: str | None, params: Mapping) -> str:
    return f"{protocol}|{scene_name or '-'}|" + json.dumps(params, sort_keys=True, separators=(",", ":"))


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
    doc = validated(_SuiteFile, raw, SuiteError, source)
    head = validated(_Head, doc.suite, SuiteError, source, "suite")
    name = head.name if head.name is not None else (Path(source).stem if source not in ("<dict>", "") else "suite")
    if not name or any(c in name for c in "/\\ "):
        raise _err(source, "suite.name", f"expected a name without spaces or slashes, got {name!r}")
    if head.scene is not None:
        _resolve_scene(head.scene, source, "suite.scene")

    sweeps: list[Sweep] = []
    seen: set[str] = set()
    for i, raw_sw in enumerate(doc.sweep):
        named = isinstance(raw_sw.get("name"), str) and raw_sw["name"]
        where = f"sweep.{raw_sw['name']}" if named else f"sweep[{i}]"
        sw = validated(_SweepTable, raw_sw, SuiteError, source, where)
        sname = sw.name
        if sname in seen:
            raise _err(source, f"{where}.name", "duplicate sweep name")
        seen.add(sname)
        sproto = sw.protocol or head.protocol
        sreal = sw.realisations if sw.realisations is not None else head.realisations
        _check_bound(sreal, source, f"{where}.realisations" if "realisations" in raw_sw else "suite.realisations")
        scene_path, scene_name = None, None
        if sproto == "rendered":
            scene_name = sw.scene if sw.scene is not None else head.scene
            if scene_name is None:
                raise _err(source, f"{where}.scene", "a rendered sweep needs a scene (sweep.scene or suite.scene)")
            scene_path = _resolve_scene(scene_name, source, f"{where}.scene")
        elif sw.scene is not None:
            raise _err(source, f"{where}.scene", "only rendered sweeps take a scene")
        # settings: (x, overrides, where)
        if sw.cases is not None:
            if sw.parameter is not None or sw.values is not None:
                raise _err(source, where, "give either parameter/values or cases, not both")
            parameter = "case"
            settings = [(float(j if cs.x is None else cs.x), dict(cs.set), f"{where}.cases[{j}].set")
                        for j, cs in enumerate(sw.cases)]
        else:
            parameter = sw.parameter
            if parameter is None:
                raise _err(source, f"{where}.parameter", "expected a parameter name")
            if sw.values is None:
                raise _err(source, f"{where}.values", "expected a non-empty list of values")
            settings = [(float(v), {parameter: v}, f"{where}.values[{j}]") for j, v in enumerate(sw.values)]
        label = sw.label if sw.label is not None else parameter
        paper = raw_sw.get("paper")
        if paper is not None:
            _check_paper(paper, source, f"{where}.paper")
        cases = []
        xs = [x for x, _, _ in settings]
        if len(set(xs)) != len(xs):
            raise _err(source, f"{where}.values" if parameter != "case" else f"{where}.cases",
                       "duplicate values (each setting of a sweep needs its own x)")
        for x, over, cwhere in settings:
            merged = {**doc.base, **sw.set, **over}
            if sproto == "paper":
                params = _resolve_paper(merged, source, cwhere)
            else:
                params = _resolve_rendered(scene_path, merged, source, cwhere)
            key = _case_key(sproto, scene_name, params)
            cases.append(Case(key=key, id=f"{sname}@{x:g}", sweep=sname, protocol=sproto,
                              scene=None if scene_path is None else str(scene_path),
                              scene_name=scene_name, params=params, x=x, realisations=sreal,
                              **_typed(sproto, params, source, cwhere)))
        sweeps.append(Sweep(name=sname, protocol=sproto, parameter=parameter, label=label,
                            display_scale=float(sw.display_scale), cases=tuple(cases), paper=paper,
                            description=sw.description))
    suite = Suite(name=name, description=head.description, source=source, seed=head.seed,
                  realisations=head.realisations, estimators=tuple(head.estimators), sweeps=tuple(sweeps),
                  sha256=sha256, raw=copy.deepcopy(dict(raw)))
    total = suite.total_realisations
    if total > MAX_TOTAL_REALISATIONS:
        raise _err(source, "realisations", f"{total:,} realisations over "
                   f"{len(suite.distinct_cases)} distinct settings exceed the maximum of "
                   f"{MAX_TOTAL_REALISATIONS:,} per run (about 2 KB of results each are held "
                   "until the report: split the suite or lower its realisations)")
    return suite


def _check_paper(paper: Mapping, source: str, where: str) -> None:
    """Refuse a paper claim whose checks are unknown or whose values do not fit them."""
    validated(_Paper, paper, SuiteError, source, where)
    chk = paper.get("check")
    single = isinstance(chk, str) or chk is None
    chks, vals = ([chk], [paper.get("value")]) if single else (chk, paper.get("value"))
    if not isinstance(chks, list) or not isinstance(vals, list) or len(chks) != len(vals):
        raise _err(source, f"{where}.value", "give one value per check (check and value both lists, or both single)")
    for c_, v_ in zip(chks, vals):
        if c_ is None:
            continue
        if c_ not in PAPER_CHECKS:
            raise _err(source, f"{where}.check", f"unknown check {c_!r} (known: {', '.join(PAPER_CHECKS)})")
        two = c_ in ("slope_in_range", "argmin_in_range")
        if two and not (isinstance(v_, list) and len(v_) == 2 and all(map(_finite, v_))):
            raise _err(source, f"{where}.value", f"check {c_} needs [low, high]")
        if not two and not _finite(v_):
            raise _err(source, f"{where}.value", f"check {c_} needs a number")


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_bound(n: int, source: str, where: str) -> None:
    """Refuse one case's realisations above :data:`MAX_TOTAL_REALISATIONS` before expanding."""
    if n > MAX_TOTAL_REALISATIONS:
        raise _err(source, where, f"{n:,} realisations exceed the maximum of "
                   f"{MAX_TOTAL_REALISATIONS:,} per run (about 2 KB of results each are held until the report)")
