"""Typed failures of the reconstruction pipeline: falsy values that name their cause.

As scikit-image's ``FailedEstimation``, a step that cannot produce a result returns a
:class:`Failure`, so that a sweep counts failures by cause and carries on; ValueError is kept for
caller errors. Every status string the pipeline can write is listed in :data:`REASONS`.
"""

from __future__ import annotations

from dataclasses import dataclass


OK = "ok"

#: Every failure cause, with what it means. The keys are the status strings of the pipeline.
REASONS: dict[str, str] = {
    # detection (whole image)
    "too_small": "the candidate highlight has fewer pixels than min_area_px",
    "touches_border": "the candidate highlight touches the image border",
    "black_border": "the candidate lies on the endoscope's black border (burnt-in text, not tissue)",
    "not_elliptical": "the candidate's shape is far from a filled ellipse (area vs. second moments)",
    "merged": "the candidate holds several saturated plateaus, or its isophote encloses another BP",
    # isophote extraction
    "bp_below_isovalue": "the brightest point is not above the isovalue (nothing to contour)",
    "no_contour": "marching squares found no contour around the brightest point",
    "contour_cut": "the isophote is cut by the ROI or image border (fit refused: allow_open=False)",
    "too_few_points": "fewer than 6 contour points (an ellipse needs 5, a check needs one more)",
    # ellipse fit
    "non_finite_points": "the contour points hold NaN or infinity",
    "degenerate_points": "the points are (nearly) collinear or coincident: the scatter is singular",
    "not_an_ellipse": "the best conic is not a real ellipse (hyperbola, parabola, line pair)",
    # pose
    "pose_failed": "the normalised conic is not a real cone: no circle pose",
    # specularity checks of a fitted candidate (simtest.reconstruct.verify)
    "overlay": "the candidate lies on a flat panel: a burnt-in overlay (text, box, UI), not tissue",
    "not_specular": "the peak is not specular: not paler than the tissue, or not well above the diffuse level",
    "cluster": "another specular peak in the isophote region, or without a rig in a glint field's angle of view",
    "bad_fit": "the isophote is no ellipse around the BP: residual too large for its size, or BP outside",
    "low_confidence": "the fit passes every check but its confidence is below min_confidence",
    "weak_twin": "a weak white peak that passes for its rig twin, until its plane fit confirms it (the rig's step "
                 "of simtest reconstruct makes it ok or not_specular)",
}


@dataclass(frozen=True)
class Failure:
    """A failed step: falsy, with a cause from :data:`REASONS` and a human-readable detail.

    Parameters
    ----------
    reason : str
        One of the keys of :data:`REASONS`.
    detail : str, optional
        Free text with the numbers that caused the failure.

    Examples
    --------
    >>> f = Failure("too_few_points", "4 points")
    >>> bool(f)
    False
    >>> str(f)
    'too_few_points: 4 points'
    """

    reason: str
    detail: str = ""

    def __post_init__(self) -> None:
        if self.reason not in REASONS:
            raise ValueError(f"unknown failure reason {self.reason!r}; known: {sorted(REASONS)}")

    def __bool__(self) -> bool:
        return False

    def __str__(self) -> str:
        return f"{self.reason}: {self.detail}" if self.detail else self.reason
