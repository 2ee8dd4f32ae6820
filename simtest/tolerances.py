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
    camera_round_trip_px : float
        pixel -> ray -> pixel through a camera model: 1e-6 px. The iterative inverses stop at
        1e-9 px and float64 rounding of a 10^3 px coordinate is ~1e-13 px, so 1e-6 px leaves
        three decades of margin while still catching any model/inverse mismatch (a wrong term
        moves pixels by far more).
    camera_jacobian_rel : float
        Analytic camera Jacobians against central finite differences: 1e-5 of the Jacobian's
        largest entry. Central differences with a step h have truncation error ~h^2 (relative
        ~1e-8 at the steps used) and rounding error ~eps |f| / h (~1e-10 relative); the inverse
        maps' Newton stop (1e-9 px) divided by the step adds at most ~1e-6 relative.
    golden_abs : float
        Agreement of a re-run with the stored outputs of the reconstruction (tests/data/golden)
        for the same settings, absolute, on unit normals, residuals (px) and eigenvalue gaps:
        1e-7. The same contour points, assembled from a smaller box (another start point, an
        integer offset added in another order), change the fit's sums in the last bits (~1e-12
        after the 6x6 eigenproblem). The circle-pose pair N+- = +-sin(phi) e1 + cos(phi) e3 is
        square-root conditioned near a right cone (sin(phi) ~ sqrt(gap)), so 1e-16 of rounding
        moves a near-fronto-parallel N+- by ~1e-8 (5e-9 on the bench's 100 px highlight). 1e-7
        (6e-6 deg) keeps a margin over that and is far below the 1e-3 deg the reports print.
        Statuses, point counts, BPs and ROIs must be identical.
    """

    conic_degenerate_rel: float = 1e-12
    exact_normal_deg: float = 1e-6
    fitted_normal_deg: float = 1e-4
    right_cone_gap: float = 1e-9
    camera_round_trip_px: float = 1e-6
    camera_jacobian_rel: float = 1e-5
    golden_abs: float = 1e-7


#: The project's tolerance table.
TOL = Tolerances()
