"""A suite's cases: the keys a case may set, the records a suite expands to, and their seeds.

:class:`ReconKeys` and :class:`RenderedKeys` validate one case's keys; :class:`Case` and
:class:`Sweep` are what :func:`simtest.harness.suite.suite_from_dict` expands a suite file to;
:func:`realisation_seed` seeds each realisation.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
from dataclasses import dataclass, field
from typing import Annotated, Any, Callable, Literal

import numpy as np
from pydantic import Field
from pydantic.dataclasses import dataclass as pydantic_dataclass

from simtest._config import CONFIG, Num
from simtest.harness.metrics import MATCH_PX
from simtest.reconstruct.settings import ReconSettings
from simtest.simulate.paper import PaperParams

__all__ = ["ReconKeys", "RenderedKeys", "RECON_KEYS", "RENDERED_KEYS", "MESH_POSE_KEYS", "stable_hash",
           "realisation_seed", "Scoring", "MeshPose", "SceneSetting", "harness_recon_settings", "Case", "Sweep"]

#: A case's keys: frozen pydantic dataclasses, unknown keys refused.
_model = functools.partial(pydantic_dataclass, frozen=True, config=CONFIG)
#: An isovalue t, relative to the highlight's peak, inside (0, 1): a closed curve inside the highlight.
_Isovalue = Annotated[Num, Field(gt=0.0, lt=1.0)]


@_model
class ReconKeys:
    """Reconstruction settings of a case, valid in both protocols (:func:`harness_recon_settings`)."""

    isovalue: _Isovalue = 0.1
    joint_isovalues: list[_Isovalue] = Field(default_factory=lambda: [0.1, 0.2, 0.3, 0.4, 0.5], min_length=2)


@_model
class RenderedKeys(ReconKeys):
    """The rendered protocol's case keys (:class:`Scoring`, :class:`MeshPose`, :class:`SceneSetting`)."""

    image: Literal["sensor", "linear"] = "sensor"
    match_px: Num = Field(MATCH_PX, gt=0.0)  # px, a distance (metrics.MATCH_PX says why)
    radius_over_distance: Num | None = Field(None, gt=0.0)  # a radius: positive
    distance_mm: Num | None = Field(None, gt=0.0)  # in front of the camera
    colon_station: Num | None = Field(None, ge=0.0, le=1.0)  # fraction of the centre line
    liver_azimuth_deg: Num | None = Field(None, ge=-360.0, le=360.0)  # one turn either way
    mesh_view_deg: Num = Field(30.0, ge=0.0, le=89.0)  # below 90: the view meets the wall
    mesh_distance_mm: Num = Field(40.0, gt=0.0)  # outside the bounding sphere
    liver_elevation_deg: Num = Field(20.0, ge=-89.0, le=89.0)  # off the poles, where azimuth is lost
    texture: Literal["scene", "per_realisation"] = "scene"


#: Reconstruction settings, valid in both protocols, with their defaults.
RECON_KEYS: dict[str, Any] = dataclasses.asdict(ReconKeys())
#: Extra keys of the rendered protocol, with their defaults.
RENDERED_KEYS: dict[str, Any] = {k: v for k, v in dataclasses.asdict(RenderedKeys()).items() if k not in RECON_KEYS}
#: Keys of :class:`MeshPose` among :data:`RENDERED_KEYS`.
MESH_POSE_KEYS = ("colon_station", "liver_azimuth_deg", "mesh_view_deg", "mesh_distance_mm", "liver_elevation_deg")


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
    """Where a ``rendered`` case places its camera on a bundled mesh.

    The colon when ``colon_station`` is set, the liver when ``liver_azimuth_deg`` is; neither: the
    scene's own camera (:func:`simtest.harness.protocols.mesh_pose_overrides`).

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
        Dotted scene overrides as the suite gives them, sorted by key.
    radius_over_distance : float or None
        Sphere or cylinder: its radius as a fraction of ``distance_mm``.
    distance_mm : float or None
        Camera to the nearest surface point along the optical axis, mm.
    mesh : MeshPose
        The camera's place on a bundled mesh, if any.
    texture : {"scene", "per_realisation"}
        The tissue's ``material.texture_seed``: the scene's, or one drawn per realisation from its
        seed, so that a case's statistics are not those of one texture's accidents.
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
        ``paper``: the known highlight, t relative to a full scale of 1; ``rendered``: every highlight
        detected at 0.7 of the full scale, t relative to the BP. No smoothing in either.
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
        If the isovalues are invalid.
    """
    t = float(isovalue)
    isovalues = (t,) + tuple(float(v) for v in joint_isovalues if float(v) != t)
    if protocol == "paper":
        return ReconSettings(isovalues=isovalues, normalise="full_scale", full_scale=1.0, smooth_sigma_px=0.0)
    return ReconSettings(isovalues=isovalues, normalise="bp", smooth_sigma_px=0.0, detection="full_scale")


@dataclass(frozen=True)
class Case:
    """One parameter setting of a sweep, run ``realisations`` times.

    Attributes
    ----------
    key : str
        Stable identity of the setting (protocol, scene and resolved parameters as canonical JSON);
        it seeds the realisations, so the same setting gets the same numbers in any suite.
    id : str
        ``<sweep>@<x>``: unique in the suite.
    sweep : str
        Name of the sweep that holds it.
    protocol : {"paper", "rendered"}
    scene : str or None
        Rendered: the base scene file (absolute path).
    scene_name : str or None
        Rendered: the scene's name as written in the suite.
    params : dict
        The case as written, flat: resolved protocol parameters or scene overrides, plus the
        reconstruction (and rendered) keys.
    x : float
        The swept value, before ``display_scale``.
    realisations : int
    recon : ReconSettings
        The reconstruction settings (:func:`harness_recon_settings`).
    paper : PaperParams or None
        ``paper`` cases only.
    scene_setting, scoring : SceneSetting or None, Scoring or None
        ``rendered`` cases only.
    """

    key: str
    id: str
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
                "scene": self.scene_name, "params": self.params, "x": self.x, "realisations": self.realisations}


@dataclass(frozen=True)
class Sweep:
    """A named list of cases varying one parameter (or an explicit list of settings).

    Attributes
    ----------
    name : str
        Unique in the suite.
    protocol : {"paper", "rendered"}
    parameter : str
        The swept parameter (a PaperParams field, a dotted scene key or a reconstruction key).
    label : str
        Axis label for plots (with its unit).
    display_scale : float
        Factor applied to ``Case.x`` in plots and tables.
    cases : tuple of Case
        In file order.
    paper : dict or None
        The paper claim this sweep checks (``claim``, ``check``, ``value``, ...), if any.
    description : str
    """

    name: str
    protocol: str
    parameter: str
    label: str
    display_scale: float
    cases: tuple[Case, ...]
    paper: dict | None = None
    description: str = ""
