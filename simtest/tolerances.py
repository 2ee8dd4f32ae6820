"""Every numerical tolerance of simtest in one documented object.

Tests and library code read their thresholds from :data:`TOL` so that a tolerance is chosen, and
justified, once (the trimesh habit). Angles are in degrees, lengths in pixels unless named.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Tolerances:
    """Numerical thresholds with the reason for each size.

    Attributes
    ----------
    conic_degenerate_rel : float
        Smallest singular value of a unit-norm conic (or eigenvalue of a unit-norm cone) below which
        it is treated as degenerate (a line pair or a point). 1e-12 is about 1e4 float64 epsilons:
        far below what a fitted ellipse of any size from 6 px to 10^4 px produces after
        normalisation, far above rounding noise.
    exact_normal_deg : float
        Agreement expected between a normal computed in closed form from an exact conic and the
        truth: 1e-6 deg (1.7e-8 rad) leaves a margin of ~1e4 over float64 rounding through an
        eigen-decomposition of a well-conditioned 3x3 matrix.
    fitted_normal_deg : float
        Agreement expected from an ellipse fitted to exact points sampled on the curve: 1e-4 deg.
        The fit solves a 6x6 generalised eigenproblem whose conditioning (after centring and scaling)
        costs about 2 more decimal digits than the closed form.
    right_cone_gap : float
        Eigenvalue gap below which a cone counts as right circular when computed in closed form:
        1e-9 relative.
    """

    conic_degenerate_rel: float = 1e-12
    exact_normal_deg: float = 1e-6
    fitted_normal_deg: float = 1e-4
    right_cone_gap: float = 1e-9


#: The project's tolerance table.
TOL = Tolerances()
