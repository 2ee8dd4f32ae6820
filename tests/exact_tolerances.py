"""The tests' tolerances on exact geometric truths, each with the reason for its size.

The package's own thresholds (and the report claims' bounds) are :data:`simtest.tolerances.TOL`; these are
what a test of an exact construction allows, so they live beside the tests.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ExactTolerances:
    """Agreement a test asks of an exact construction.

    Attributes
    ----------
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
    exact_image_normal_deg : float
        Normal error allowed to a light-aware fit of an exact float image (no noise): 0.01 deg.
        What remains is the contour's spline interpolation (isophote points refined to ~1e-4 px)
        and the fits' stopping tolerances, both measured below 1e-4 deg; the margin covers the
        worst conditioned cases (60 mm, 50 deg tilt, epsilon/d = 0.05).
    exact_image_depth_rel : float
        Relative depth error allowed in the same setting: 1e-3 (0.1 %; measured below 2e-6).
    small_isophote_gap_abs : float
        Agreement between the eigenvalue gap of an exact isophote cone on a curved patch, at a
        cone half-angle gamma_0 = 0.1 deg, and its small-isophote limit 1 - rho^2
        (:func:`simtest.geometry.curvature.predicted_eigenvalue_gap`): 1e-4. The limit drops terms of order
        gamma_0^2 / (1 + k d)^2, at most 16 gamma_0^2 = 4.9e-5 where |1 + k d| >= 0.25 (measured:
        up to 5.5e-5 over 300 random patches, curvatures -0.05 to 0.2 /mm at 10 to 50 mm).
    """

    exact_normal_deg: float = 1e-6
    fitted_normal_deg: float = 1e-4
    right_cone_gap: float = 1e-9
    camera_round_trip_px: float = 1e-6
    camera_jacobian_rel: float = 1e-5
    exact_image_normal_deg: float = 0.01
    exact_image_depth_rel: float = 1e-3
    small_isophote_gap_abs: float = 1e-4


#: The tolerances the tests read.
EXACT = ExactTolerances()
