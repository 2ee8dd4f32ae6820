"""Projective geometry of the method: conics, circle pose, cameras and angles (numpy only).

Nothing here imports Mitsuba or any renderer: the reconstruction core runs on real images too.
"""

from simtest.geometry.angles import angle_between_deg, face_camera
from simtest.geometry.camera import (
    Intrinsics,
    IntrinsicsError,
    bp_ray_normal,
    load_intrinsics,
    look_at,
    pixel_to_ray,
    project_points,
    save_intrinsics,
    undistort_points,
    validate_intrinsics,
)
from simtest.geometry.conics import (
    CirclePose,
    ConeAxis,
    Ellipse,
    circle_pose,
    conic_kind,
    conic_to_ellipse,
    cone_axis,
    ellipse_to_conic,
    normalised_conic,
    project_circle,
    sample_ellipse,
)

__all__ = [
    "CirclePose",
    "ConeAxis",
    "Ellipse",
    "Intrinsics",
    "IntrinsicsError",
    "angle_between_deg",
    "bp_ray_normal",
    "circle_pose",
    "conic_kind",
    "conic_to_ellipse",
    "cone_axis",
    "ellipse_to_conic",
    "face_camera",
    "load_intrinsics",
    "look_at",
    "normalised_conic",
    "pixel_to_ray",
    "project_circle",
    "project_points",
    "sample_ellipse",
    "save_intrinsics",
    "undistort_points",
    "validate_intrinsics",
]
