"""Light rigs: the point lights of an endoscope tip, in the camera frame (OpenCV axes, mm).

A light's radiant intensity toward a unit direction w is ``intensity * max(w_z, 0) ** profile_exponent``,
falling as ``1 / s**2`` (``"inverse_square"``) or not at all (``"none"``). Without a rig simtest uses
:meth:`LightRig.colocated`, the paper's co-located case. Intensities are relative weights within
[:data:`MIN_INTENSITY`, :data:`MAX_INTENSITY`] (beyond is a unit slip, and 1e300 overflows the sums). A
scope's rig (a camera file's ``"lights"``) is also checked by :func:`check_scope_rig`: a light
:data:`MAX_AHEAD_MM` or more ahead of the lens sits behind the tissue of most views (a fit of it gives a
confident wrong answer), one beyond :data:`MAX_DISTANCE_MM` is on no scope (m or um taken for mm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simtest._checks import finite_number

__all__ = ["FALLOFFS", "MAX_AHEAD_MM", "MAX_DISTANCE_MM", "MAX_INTENSITY", "MAX_LIGHTS", "MAX_PROFILE_EXPONENT",
           "MIN_INTENSITY", "Light", "LightRig", "LightRigError", "check_scope_rig"]

#: The falloff laws a light may have.
FALLOFFS = ("inverse_square", "none")
#: The most lights a rig may have (endoscope tips carry one to a few light guides).
MAX_LIGHTS = 8
#: Bounds of a light's intensity (a relative weight; the module docstring says why).
MIN_INTENSITY = 1e-9
MAX_INTENSITY = 1e9
#: The largest emission-profile exponent m: a 2.1 deg half-power beam (a light guide's fibres, NA 0.2 to 0.9,
#: give m = 0.7 to 45); beyond it a value is a slip.
MAX_PROFILE_EXPONENT = 1000.0
#: A scope's light lies less than this far ahead of the lens plane (z < 20 mm), mm.
MAX_AHEAD_MM = 20.0
#: A scope's light lies at most this far from the lens, mm.
MAX_DISTANCE_MM = 200.0


class LightRigError(ValueError):
    """A light or rig is invalid; the message names the light and the field."""


@dataclass(frozen=True)
class Light:
    """One point light.

    Parameters
    ----------
    position_mm : array_like of shape (3,)
        Position in the camera frame, mm.
    intensity : float
        Relative weight, in [:data:`MIN_INTENSITY`, :data:`MAX_INTENSITY`].
    falloff : {"inverse_square", "none"}
        Distance law of the irradiance.
    profile_exponent : float
        m in [0, :data:`MAX_PROFILE_EXPONENT`] of the cos^m angular profile about +z.

    Raises
    ------
    LightRigError
        A non-finite or boolean number, or a value outside its range.
    """

    position_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    intensity: float = 1.0
    falloff: str = "inverse_square"
    profile_exponent: float = 0.0

    def __post_init__(self) -> None:
        p = self.position_mm
        if isinstance(p, np.ndarray):
            p = p.tolist()
        if not isinstance(p, (list, tuple)) or len(p) != 3:
            raise LightRigError(f"position_mm: must be [x, y, z] in mm, got {self.position_mm!r}")
        pos = tuple(finite_number(v, f"position_mm[{i}]", LightRigError) for i, v in enumerate(p))
        object.__setattr__(self, "position_mm", pos)
        inten = finite_number(self.intensity, "intensity", LightRigError)
        if inten <= 0:
            raise LightRigError(f"intensity: must be > 0, got {self.intensity!r}")
        if not MIN_INTENSITY <= inten <= MAX_INTENSITY:
            raise LightRigError(f"intensity: must be within [{MIN_INTENSITY:g}, {MAX_INTENSITY:g}] (a relative "
                                f"weight), got {self.intensity!r}")
        object.__setattr__(self, "intensity", inten)
        if self.falloff not in FALLOFFS:
            raise LightRigError(f"falloff: must be one of {list(FALLOFFS)}, got {self.falloff!r}")
        m = finite_number(self.profile_exponent, "profile_exponent", LightRigError)
        if m < 0:
            raise LightRigError(f"profile_exponent: must be >= 0, got {self.profile_exponent!r}")
        if m > MAX_PROFILE_EXPONENT:
            raise LightRigError(f"profile_exponent: {self.profile_exponent!r} is over {MAX_PROFILE_EXPONENT:g} (the "
                                f"cos^m of a 2.1 deg half-power beam; a light guide's is 0.7 to 45)")
        object.__setattr__(self, "profile_exponent", m)

    @property
    def position(self) -> np.ndarray:
        """ndarray of shape (3,): the position, mm, camera frame."""
        return np.array(self.position_mm)

    def to_json_dict(self) -> dict:
        """The camera file's JSON object for this light."""
        return {"position_mm": list(self.position_mm), "intensity": self.intensity, "falloff": self.falloff,
                "profile_exponent": self.profile_exponent}


@dataclass(frozen=True)
class LightRig:
    """The lights of a scope tip, 1 to :data:`MAX_LIGHTS`.

    Parameters
    ----------
    lights : tuple of Light
        The lights.

    Raises
    ------
    LightRigError
        No light, more than :data:`MAX_LIGHTS`, or an entry that is not a :class:`Light`.

    Examples
    --------
    >>> LightRig.colocated().is_colocated
    True
    """

    lights: tuple[Light, ...]

    def __post_init__(self) -> None:
        lights = tuple(self.lights)
        if not 1 <= len(lights) <= MAX_LIGHTS:
            raise LightRigError(f"lights: need 1 to {MAX_LIGHTS} lights, got {len(lights)}")
        for i, light in enumerate(lights):
            if not isinstance(light, Light):
                raise LightRigError(f"lights[{i}]: not a Light ({light!r})")
        object.__setattr__(self, "lights", lights)

    @classmethod
    def colocated(cls) -> LightRig:
        """One isotropic inverse-square light at the camera centre (the paper's co-located case)."""
        return cls((Light(),))

    @property
    def is_colocated(self) -> bool:
        """True when every light sits at the camera centre."""
        return all(light.position_mm == (0.0, 0.0, 0.0) for light in self.lights)

    @property
    def light_places(self) -> int:
        """How many different places the lights sit at (a smooth patch shows at most one lobe per place)."""
        return len({light.position_mm for light in self.lights})

    @property
    def has_separate_lights(self) -> bool:
        """True when at least two lights sit at different places."""
        return self.light_places >= 2

    @property
    def positions(self) -> np.ndarray:
        """ndarray of shape (L, 3): light positions, mm, camera frame."""
        return np.array([light.position_mm for light in self.lights])

    def __len__(self) -> int:
        return len(self.lights)

    def to_json_list(self) -> list[dict]:
        """The camera file's ``"lights"`` list."""
        return [light.to_json_dict() for light in self.lights]


def check_scope_rig(rig: LightRig) -> LightRig:
    """Check that a rig can be a scope's lights (the module docstring's bounds).

    Parameters
    ----------
    rig : LightRig
        Lights in the camera frame, mm.

    Returns
    -------
    LightRig
        ``rig``, unchanged.

    Raises
    ------
    LightRigError
        Naming the first light that lies :data:`MAX_AHEAD_MM` or more ahead of the lens plane
        (``lights[i].position_mm[2]``) or farther than :data:`MAX_DISTANCE_MM` from the lens.
    """
    for i, light in enumerate(rig.lights):
        x, y, z = light.position_mm
        if z >= MAX_AHEAD_MM:
            raise LightRigError(
                f"lights[{i}].position_mm: z = {z:g} mm puts the light {MAX_AHEAD_MM:g} mm or more ahead of "
                f"the lens, behind the tissue of most views; a scope's light guides sit within a few mm "
                f"of the lens plane (z < {MAX_AHEAD_MM:g})")
        dist = math.sqrt(x * x + y * y + z * z)
        if dist > MAX_DISTANCE_MM:
            raise LightRigError(
                f"lights[{i}].position_mm: {dist:.4g} mm from the lens, more than {MAX_DISTANCE_MM:g} mm: "
                f"on no scope (mm expected, not um or m)")
    return rig
