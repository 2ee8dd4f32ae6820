"""Projective geometry of the method: conics, circle pose, camera models, light rigs and angles.

Nothing here imports Mitsuba or any renderer: the reconstruction core runs on real images too.
"""

from simtest.geometry.angles import angle_between_deg
from simtest.geometry.camera import (IntrinsicsError, bp_ray_normal, look_at, pixel_to_ray, project_points,
                                     validate_intrinsics)
from simtest.geometry.camera_file import CameraFile, CameraFileError, load_camera, save_camera, save_intrinsics
from simtest.geometry.cameras import CameraModel, FisheyeCamera, OmnidirectionalCamera, PinholeCamera, c3vd_camera
from simtest.geometry.conics import (CirclePose, ConeAxis, Ellipse, circle_pose, conic_kind, conic_to_ellipse,
                                     cone_axis, normalised_conic, project_circle)
from simtest.geometry.lights import Light, LightRig, LightRigError

__all__ = ["CameraFile", "CameraFileError", "CameraModel", "CirclePose", "ConeAxis", "Ellipse", "FisheyeCamera",
           "IntrinsicsError", "Light", "LightRig", "LightRigError", "OmnidirectionalCamera", "PinholeCamera",
           "angle_between_deg", "bp_ray_normal", "c3vd_camera", "circle_pose", "conic_kind", "conic_to_ellipse",
           "cone_axis", "load_camera", "look_at", "normalised_conic", "pixel_to_ray", "project_circle",
           "project_points", "save_camera", "save_intrinsics", "validate_intrinsics"]
