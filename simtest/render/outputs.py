"""What a render gives: :class:`RenderResult`, and its output folder (:func:`write_render`)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from simtest._io import check_output_folder, jsonable, replace_output_folder
from simtest.geometry.camera_file import save_camera, save_intrinsics
from simtest.geometry.cameras import CameraModel, PinholeCamera
from simtest.geometry.lights import Light, LightRig
from simtest.geometry.response import video_response
from simtest.render.endoscope import guide_radius_mm
from simtest.render.sensor import video_frame
from simtest.scene.spec import SceneSpec, scene_to_dict
from simtest.simulate.truth import HighlightTruth

#: Coverage from which a pixel counts as tissue for the "tissue" metering of the auto-exposure
#: (``sensor.metering``): half the pixel or more on the surface.
TISSUE_COVERAGE = 0.5


@dataclass(frozen=True)
class RenderResult:
    """Everything one render produces. Images are (H, W[, 3]) arrays, camera frame, mm.

    Attributes
    ----------
    linear : ndarray of shape (H, W), float32
        Linear radiance (specular + diffuse); 0 outside a video sensor's field stop (so are ``rgb``, ``specular``).
    sensor : ndarray of shape (H, W), uint8 or uint16
        After exposure, noise, clipping, gamma and quantisation.
    specular : ndarray of shape (H, W), float32
        Specular-only linear radiance.
    normals : ndarray of shape (H, W, 3), float32
        Unit shading normals facing the camera; NaN outside ``mask``.
    depth : ndarray of shape (H, W), float32
        z-depth, mm; NaN outside ``mask``.
    distance : ndarray of shape (H, W), float32
        Distance from the camera centre to the pixel's mean surface point, mm; NaN outside ``mask``.
    position : ndarray of shape (H, W, 3), float32
        Surface point, camera frame, mm; NaN outside ``mask``.
    mask : ndarray of shape (H, W), bool
        Pixels entirely covered by the surface.
    coverage : ndarray of shape (H, W), float32
        Fraction of each pixel covered by the surface.
    K : ndarray of shape (3, 3)
        Intrinsics, pixel centres at integer coordinates.
    cam_to_world : ndarray of shape (4, 4)
        Camera pose in the scene's world frame.
    light_pos : ndarray of shape (3,)
        Point-light position, camera frame, mm.
    highlights : list of HighlightTruth
    variant : str
        Mitsuba variant used.
    seed : int
    spec : SceneSpec
    camera : CameraModel or None
        The camera model of an endoscope render; None for Mitsuba's perspective sensor (the pinhole ``K``).
    lights : LightRig or None
        The light rig of an endoscope render; None for the one light at ``light_pos``.
    rgb : ndarray of shape (H, W, 3), float32, or None
        Linear RGB radiance of a tissue render; None when the image is grey.
    shading_normals : ndarray of shape (H, W, 3), float32, or None
        Unit shading normals with the tissue's micro-relief (``normals`` is the macro normal); None without.
    video : ndarray of shape (H, W, 3), uint8, or None
        The video frame when the sensor made one (``sensor`` is then its luma).
    field_stop : ndarray of shape (H, W), bool, or None
        Pixels inside the scope's field stop (no light and no truth outside); None: the whole film.
    albedo : ndarray of shape (H, W, 3), float32, or None
        Linear RGB diffuse albedo at each pixel centre's surface point, NaN outside ``mask``; None without tissue.
    relief_highlights : list of ReliefHighlight
        The micro-relief's glints, in frame, lit and unoccluded (:func:`simtest.render.truth.relief_highlights`).
    """

    linear: np.ndarray
    sensor: np.ndarray
    specular: np.ndarray
    normals: np.ndarray
    depth: np.ndarray
    distance: np.ndarray
    position: np.ndarray
    mask: np.ndarray
    coverage: np.ndarray
    K: np.ndarray
    cam_to_world: np.ndarray
    light_pos: np.ndarray
    highlights: list[HighlightTruth]
    variant: str
    seed: int
    spec: SceneSpec = field(repr=False)
    camera: CameraModel | None = None
    lights: LightRig | None = None
    rgb: np.ndarray | None = None
    shading_normals: np.ndarray | None = None
    video: np.ndarray | None = field(default=None, repr=False)
    field_stop: np.ndarray | None = field(default=None, repr=False)
    albedo: np.ndarray | None = field(default=None, repr=False)
    relief_highlights: list = field(default_factory=list)

    @property
    def frame(self) -> np.ndarray:
        """The 8-bit RGB video frame (H, W, 3) of the scene's sensor (developed from the linear image if not made)."""
        if self.video is not None:
            return self.video
        return video_frame(self.rgb if self.rgb is not None else self.linear, self.spec.sensor, self.seed,
                           tissue=self.coverage >= TISSUE_COVERAGE)

    @property
    def camera_model(self) -> CameraModel:
        """The camera model of the film (a pinhole with ``K`` for a perspective render)."""
        if self.camera is not None:
            return self.camera
        H, W = self.linear.shape[:2]
        return PinholeCamera(self.K, image_size=(W, H))

    @property
    def light_rig(self) -> LightRig:
        """The lights of the render, camera frame (one light at ``light_pos`` unless a rig)."""
        if self.lights is not None:
            return self.lights
        falloff = "none" if self.spec.light.falloff == "cancel" else "inverse_square"
        return LightRig((Light(tuple(float(x) for x in self.light_pos), self.spec.light.intensity, falloff),))


#: File names of one render's output set (``write_render``)
RENDER_FILES = ("image.png", "intrinsics.json", "ground_truth.npz", "highlights.json", "camera.json", "frame.png")


def write_render(result: RenderResult, out_dir: str | Path) -> dict[str, Path]:
    """Write a render to ``out_dir`` as one set (:func:`simtest._io.replace_output_folder`).

    Files: ``image.png`` (the sensor image, 8 or 16 bit grey), ``intrinsics.json``, ``ground_truth.npz``
    (``normals``, ``depth``, ``distance``, ``position``, ``mask``, ``linear``, ``specular``, ``coverage``, ``K``,
    ``cam_to_world``, ``light_pos`` (the first light), ``light_positions`` (L, 3), ``field_stop`` (all True without
    one); tissue renders add ``rgb``, ``shading_normals`` and ``albedo``), ``highlights.json`` (``highlights``
    with ``kind`` "macro", ``relief_highlights``, every light, the scene, seed and variant), ``camera.json``
    (model, rig and, with a video sensor, its ``"response"``) and ``frame.png`` (the 8-bit RGB video frame).

    Returns
    -------
    dict
        File role -> path.

    Raises
    ------
    OutputFolderError
        If ``out_dir`` is a file or holds other files than a render's.
    OSError
        If writing fails (``out_dir`` then keeps its previous content, or does not exist).
    """
    out = Path(out_dir).absolute()
    check_output_folder(out, RENDER_FILES)
    names = dict(zip(("image", "intrinsics", "ground_truth", "highlights", "camera", "frame"), RENDER_FILES))
    img = result.sensor
    pil = Image.fromarray(img, mode="L") if img.dtype == np.uint8 else Image.fromarray(img.astype(np.uint16))
    H, W = result.linear.shape[:2]
    rig = result.light_rig
    meta = {"scene": result.spec.name, "seed": result.seed, "variant": result.variant,
            "light_pos_mm": [float(x) for x in result.light_pos],
            "lights": [{**jsonable(dataclasses.asdict(light)), "diameter_mm": 2.0 * guide_radius_mm(result.spec)}
                       for light in rig.lights],
            "image_size": [W, H], "highlights": [{**h.to_dict(), "kind": "macro"} for h in result.highlights],
            "relief_highlights": [h.to_dict() for h in result.relief_highlights],
            "spec": scene_to_dict(result.spec)}
    stop = result.field_stop if result.field_stop is not None else np.ones((H, W), dtype=bool)
    light_positions = np.array([light.position_mm for light in rig.lights], dtype=np.float64).reshape(-1, 3)

    def fill(tmp: Path) -> None:
        paths = {k: tmp / v for k, v in names.items()}
        # plain writes: replace_output_folder fsyncs them and swaps the whole folder in
        pil.save(paths["image"], format="PNG")
        save_intrinsics(paths["intrinsics"], result.K, dist_coeffs=None, image_size=(W, H))
        np.savez_compressed(
            paths["ground_truth"], normals=result.normals, depth=result.depth, distance=result.distance,
            position=result.position, mask=result.mask, linear=result.linear, specular=result.specular,
            coverage=result.coverage, K=result.K, cam_to_world=result.cam_to_world, light_pos=result.light_pos,
            light_positions=light_positions, field_stop=stop, **({"rgb": result.rgb} if result.rgb is not None else {}),
            **({"albedo": result.albedo} if result.albedo is not None else {}),
            **({"shading_normals": result.shading_normals} if result.shading_normals is not None else {}))
        paths["highlights"].write_text(json.dumps(meta, indent=2), encoding="utf-8")
        # a video frame's camera file carries its sensor's response (the fits run on linear intensities)
        save_camera(paths["camera"], result.camera_model, result.light_rig,
                    video_response(result.spec.sensor) if result.video is not None else None)
        Image.fromarray(result.frame, mode="RGB").save(paths["frame"], format="PNG")

    replace_output_folder(out, fill, owned=RENDER_FILES)
    return {k: out / v for k, v in names.items()}
