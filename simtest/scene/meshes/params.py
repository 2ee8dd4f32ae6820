"""Parameters of the mesh generators, their checks, the seeds, and the error of a bad mesh input."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any

import numpy as np
from pydantic import BeforeValidator, Field
from pydantic.dataclasses import dataclass as pydantic_dataclass

from simtest._config import CONFIG, Int, Num, validated

#: Seed of the committed meshes (``simtest meshes build`` default).
DEFAULT_SEED = 0

#: Stable integer keys mixed with the root seed (np.random.SeedSequence([seed, key])).
_SEED_KEYS = {"colon": 1001, "liver": 1002, "colon_haustral": 1003}


class MeshError(ValueError):
    """Bad mesh parameters or a bad mesh file (a ValueError); the message names the file or parameter."""


def _python_scalar(v: Any) -> Any:
    return v.item() if isinstance(v, np.generic) else v


#: A finite float field (an int, or a numpy scalar, is taken); an integer field likewise.
MeshNum = Annotated[Num, BeforeValidator(_python_scalar)]
MeshInt = Annotated[Int, BeforeValidator(_python_scalar)]


def _check_bend(p, radius_mm: float, radius: str) -> None:
    """MeshError where the centre-line curvature bound |x''| + |y''| (t ~ arc length) times ``radius_mm`` is >= 0.8."""
    w = 2.0 * math.pi / p.bend_wavelength_mm
    kappa_max = p.bend_mm * w * w * (1.0 + p.bend_3d * 0.49)
    if kappa_max * radius_mm >= 0.8:
        raise MeshError(f"{type(p).__name__}: bend_mm: the centre line bends too sharply for the tube (curvature "
                        f"up to {kappa_max:.3g} /mm times radius {radius} mm >= 0.8 would fold the wall); "
                        f"lower bend_mm or raise bend_wavelength_mm")


@pydantic_dataclass(frozen=True, config=CONFIG)
class ColonParams:
    """Parameters of :func:`build_colon` (lengths in mm).

    Attributes
    ----------
    length_mm : float
        Extent of the centre line along z (its parameter t runs over [0, length_mm]).
    radius_mm : float
        Wall distance from the centre line between folds and away from the taeniae.
    bend_mm : float
        Lateral amplitude of the centre line in x (in y it is ``bend_3d`` times this).
    bend_wavelength_mm : float
        Wavelength of the lateral meander in x (the y meander has 1/0.7 times this).
    bend_3d : float
        Ratio of the y amplitude to the x amplitude (0: a planar centre line).
    fold_depth_mm : float
        How far a fold crest reaches into the lumen (0: no folds).
    fold_spacing_mm : float
        Mean arc-length distance between folds.
    fold_sharpness : float
        von Mises concentration kappa of the fold profile exp(kappa (cos theta - 1)); larger is
        narrower (crest curvature about depth * kappa * (2 pi / spacing)^2).
    fold_jitter : float
        Relative variation of the local fold spacing, in [0, 0.9] (seeded phase).
    taenia_count : int
        Number of taeniae (longitudinal bands) around the wall.
    taenia_relief : float
        Fraction of the fold depth removed on a taenia (folds are crescents between taeniae).
    taenia_indent : float
        Fractional inward pull of the wall on a taenia (a rounded-polygon cross-section).
    n_around, n_along : int
        Vertices per ring, number of rings.
    ring_curvature_weight_mm : float
        Ring placement: rings are equally spaced in w(t) = wall length + this * turning angle of
        the mean wall profile, so folds get denser rings (0: equal wall length).
    """

    length_mm: Annotated[MeshNum, Field(gt=0.0)] = 240.0
    radius_mm: Annotated[MeshNum, Field(gt=0.0)] = 25.0
    bend_mm: Annotated[MeshNum, Field(ge=0.0)] = 18.0
    bend_wavelength_mm: Annotated[MeshNum, Field(gt=0.0)] = 260.0
    bend_3d: Annotated[MeshNum, Field(ge=0.0)] = 0.5
    fold_depth_mm: Annotated[MeshNum, Field(ge=0.0)] = 5.0
    fold_spacing_mm: Annotated[MeshNum, Field(gt=0.0)] = 32.0
    fold_sharpness: Annotated[MeshNum, Field(gt=0.0)] = 1.5
    fold_jitter: Annotated[MeshNum, Field(ge=0.0, le=0.9)] = 0.2
    taenia_count: Annotated[MeshInt, Field(ge=1, le=12)] = 3
    taenia_relief: Annotated[MeshNum, Field(ge=0.0, le=1.0)] = 0.6
    taenia_indent: Annotated[MeshNum, Field(ge=0.0, le=0.5)] = 0.04
    n_around: Annotated[MeshInt, Field(ge=8, le=4096)] = 96
    n_along: Annotated[MeshInt, Field(ge=4, le=100000)] = 300
    ring_curvature_weight_mm: Annotated[MeshNum, Field(ge=0.0)] = 40.0

    def validate(self) -> None:
        """Check that the lumen neither closes nor folds (the fields' ranges are their types').

        Raises
        ------
        MeshError
            Naming the parameter at fault and its value.
        """
        r_min = self.radius_mm * (1.0 - self.taenia_indent) - self.fold_depth_mm
        limit = self.radius_mm * (0.9 - self.taenia_indent)
        if r_min <= 0.1 * self.radius_mm:
            raise MeshError(f"ColonParams: fold_depth_mm: {self.fold_depth_mm!r} closes the lumen "
                            f"(smallest wall distance {r_min:.3g} mm with radius_mm={self.radius_mm!r}, "
                            f"taenia_indent={self.taenia_indent!r}); keep it below {limit:.3g}")
        _check_bend(self, self.radius_mm, repr(self.radius_mm))


@pydantic_dataclass(frozen=True, config=CONFIG)
class LiverParams:
    """Parameters of :func:`build_liver`.

    Attributes
    ----------
    extent_mm : float
        Largest extent of the mesh's axis-aligned bounding box (the mesh is scaled to it).
    axis_y, axis_z : float
        Semi-axes of the base ellipsoid relative to the x semi-axis (left-right).
    lobe_amplitude : float
        Standard deviation of the degree-1 coefficients of the seeded radial log-deformation
        (degree d gets lobe_amplitude / d).
    lobe_degree : int
        Highest polynomial degree of the seeded deformation (spherical harmonics up to it).
    taper : float
        Deterministic left-right asymmetry: log-radius + taper * w_x (w the unit direction).
    wedge : float
        Deterministic wedge: log-radius - wedge * w_x * w_z^2, so the surface is thick on the
        -x side (a large lobe) and thin on the +x side (a small lobe), as a liver is.
    bulge : float
        Deterministic top-bottom asymmetry: log-radius + bulge * (w_z^2 - w_z^3) / 2, so the -z
        side bulges more than the +z side.
    n_vertices : int
        Number of vertices (a spherical Fibonacci lattice of directions, triangulated by its
        convex hull, i.e. a spherical Delaunay triangulation).
    density_exponent : float
        Vertex placement between uniform in direction (0; the most even normal change per edge
        on the default shapes) and uniform in the normal of the base ellipsoid (1: density
        proportional to its Gaussian curvature).
    """

    extent_mm: Annotated[MeshNum, Field(gt=0.0)] = 180.0
    axis_y: Annotated[MeshNum, Field(ge=0.05, le=20.0)] = 0.72
    axis_z: Annotated[MeshNum, Field(ge=0.05, le=20.0)] = 0.45
    lobe_amplitude: Annotated[MeshNum, Field(ge=0.0, le=0.5)] = 0.2
    lobe_degree: Annotated[MeshInt, Field(ge=0, le=8)] = 4
    taper: Annotated[MeshNum, Field(ge=-1.0, le=1.0)] = 0.25
    wedge: Annotated[MeshNum, Field(ge=-2.0, le=2.0)] = 0.8
    bulge: Annotated[MeshNum, Field(ge=-1.0, le=1.0)] = 0.3
    n_vertices: Annotated[MeshInt, Field(ge=12, le=2000000)] = 16000
    density_exponent: Annotated[MeshNum, Field(ge=0.0, le=1.0)] = 0.0


def _make_params(cls: type, params: Mapping[str, Any], where: str) -> Any:
    """``cls`` from ``params``, checked by pydantic then ``validate``; else MeshError ``"<where>: <field>: ..."``."""
    obj = validated(cls, dict(params), MeshError, where)
    if hasattr(obj, "validate"):
        obj.validate()
    return obj


def _check_seed(seed: Any, where: str) -> int:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise MeshError(f"{where}: seed: expected a non-negative integer, got {seed!r}")
    return int(seed)


def _rng(seed: int, name: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, _SEED_KEYS[name]]))


@pydantic_dataclass(frozen=True, config=CONFIG)
class HaustralParams:
    """Parameters of :func:`~simtest.scene.meshes.haustral.build_haustral_colon` (lengths in mm).

    Defaults are a distended transverse-to-descending colon (approximate values):

    - lumen diameter: transverse colon under 6 cm (commonly quoted radiology values, e.g.
      https://www.seekhealthz.com/health/normal-cross-sectional-imaging-appearance-of-the-colon/);
    - fold height: 9.5 +- 3.7 mm transverse, 6.5 +- 3.1 mm descending (A. C. Thompson et al.,
      "Taller haustral folds in the proximal colon", Journal of Colon and Rectal Cancer, 2016);
    - taeniae coli: three bands about 1 cm wide, slight indentations, crescent folds between them
      ("Normal anatomy of the colon and rectum", Thieme, doi:10.1055/b-0034-91855);
    - fold spacing about 2 to 3 cm, thickness 3 to 5 mm: estimates from endoscopic and CT images.

    Attributes
    ----------
    length_mm : float
        Range of the fold coordinate v (about the centre line's length; its parameter is z).
    diameter_mm : float
        Lumen diameter between folds, away from the taeniae, before the haustral bulge
        (5 cm: the transverse colon's upper half of < 6 cm).
    diameter_variation, diameter_wavelength_mm : float
        Relative amplitude and wavelength of the slow, seeded sinusoidal change of the diameter.
    bend_mm, bend_wavelength_mm, bend_3d : float
        Centre line ``(A (sin(w u + px) - sin px), A bend_3d (sin(0.7 w u + py) - sin py), u)``
        with ``A = bend_mm``, ``w = 2 pi / bend_wavelength_mm``, seeded phases.
    fold_spacing_mm : float
        Mean distance between neighbouring folds along the centre line (about 2 to 3 cm).
    fold_jitter : float
        Relative variation of the local fold spacing, in [0, 0.5] (seeded phase).
    fold_height_mm : float
        Mean height of a fold crest above the wall midway between taeniae (8 mm: between the
        transverse 9.5 and descending 6.5 mm of Thompson et al. 2016).
    fold_height_variation : float
        Relative amplitude of the slow, seeded change of the height from fold to fold.
    fold_thickness_mm : float
        Full width of a fold at half its height, along the centre line (at most that of a
        Gaussian crest with ``fold_crest_radius_mm``; a wider request gets that width).
    fold_crest_radius_mm : float
        Radius of curvature of a fold's profile at its crest, along the centre line, for a fold
        of the mean height: the sharpness (smaller is sharper).
    fold_crescent_mm, fold_stagger_mm : float
        How far a crest bows along the centre line between two taeniae; amplitude of the folds'
        offset around the circumference, ``stagger sin(theta)`` (the sectors' folds do not line up).
    taenia_width_mm, taenia_indent_mm : float
        Full width at half depth of each of the three taeniae (about 1 cm); inward pull of the wall there.
    taenia_fold_relief : float
        Fraction of the fold height lost on a taenia, in [0, 1] (folds are interrupted there).
    haustra_bulge_mm : float
        Outward bulge of the wall midway between folds and between taeniae (the haustra).
    n_around, n_along : int
        Vertices per ring, number of rings.
    ring_curvature_weight_mm : float
        Rings are equally spaced in wall length + this * turning angle of the wall profile, so
        fold crests get denser rings.
    """

    length_mm: Annotated[MeshNum, Field(gt=0.0)] = 160.0
    diameter_mm: Annotated[MeshNum, Field(gt=0.0)] = 50.0
    diameter_variation: Annotated[MeshNum, Field(ge=0.0, le=0.5)] = 0.08
    diameter_wavelength_mm: Annotated[MeshNum, Field(gt=0.0)] = 150.0
    bend_mm: Annotated[MeshNum, Field(ge=0.0)] = 20.0
    bend_wavelength_mm: Annotated[MeshNum, Field(gt=0.0)] = 300.0
    bend_3d: Annotated[MeshNum, Field(ge=0.0, le=2.0)] = 0.6
    fold_spacing_mm: Annotated[MeshNum, Field(gt=0.0)] = 25.0
    fold_jitter: Annotated[MeshNum, Field(ge=0.0, le=0.5)] = 0.15
    fold_height_mm: Annotated[MeshNum, Field(ge=0.0)] = 8.0
    fold_height_variation: Annotated[MeshNum, Field(ge=0.0, le=0.9)] = 0.25
    fold_thickness_mm: Annotated[MeshNum, Field(gt=0.0)] = 4.0
    fold_crest_radius_mm: Annotated[MeshNum, Field(gt=0.0)] = 1.5
    fold_crescent_mm: Annotated[MeshNum, Field(ge=0.0)] = 3.0
    fold_stagger_mm: Annotated[MeshNum, Field(ge=0.0)] = 4.0
    taenia_width_mm: Annotated[MeshNum, Field(gt=0.0)] = 10.0
    taenia_indent_mm: Annotated[MeshNum, Field(ge=0.0)] = 2.0
    taenia_fold_relief: Annotated[MeshNum, Field(ge=0.0, le=1.0)] = 0.85
    haustra_bulge_mm: Annotated[MeshNum, Field(ge=0.0)] = 3.0
    n_around: Annotated[MeshInt, Field(ge=8, le=4096)] = 160
    n_along: Annotated[MeshInt, Field(ge=4, le=100000)] = 400
    ring_curvature_weight_mm: Annotated[MeshNum, Field(ge=0.0)] = 6.0

    def validate(self) -> None:
        """Check the lumen against closing or folding (the fields' ranges are their types').

        Raises
        ------
        MeshError
            Naming the parameter that is out of range and its value.
        """
        r0 = 0.5 * self.diameter_mm
        r_min = (r0 * (1.0 - self.diameter_variation) - self.taenia_indent_mm
                 - self.fold_height_mm * (1.0 + self.fold_height_variation))
        if r_min <= 0.25 * r0:
            raise MeshError(f"HaustralParams: fold_height_mm: {self.fold_height_mm!r} closes the lumen (smallest "
                            f"wall distance {r_min:.3g} mm with diameter_mm={self.diameter_mm!r}); keep the wall "
                            f"at least a quarter of the radius from the centre line")
        if self.fold_crescent_mm + self.fold_stagger_mm >= 0.4 * self.fold_spacing_mm:
            raise MeshError(f"HaustralParams: fold_crescent_mm + fold_stagger_mm = "
                            f"{self.fold_crescent_mm + self.fold_stagger_mm!r} must stay below 0.4 fold_spacing_mm "
                            f"({0.4 * self.fold_spacing_mm:.3g}): neighbouring folds would overlap")
        r_max = r0 * (1.0 + self.diameter_variation) + self.haustra_bulge_mm
        _check_bend(self, r_max, f"{r_max:.3g}")
