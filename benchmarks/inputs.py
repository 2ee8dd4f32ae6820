"""The benchmarks' pinned inputs: synthetic highlights and frames, the real banner and its
1350 x 1080 mosaic, the bench video, the rendered colonoscope frame.

Seeds are fixed (0 and 12) and the real frames are read from the clone's ``tests/data/real``, so a
figure measures the same pixels on every run; the tests and ``tests/golden.py`` read these too.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import cv2
import numpy as np

from simtest.geometry.camera import pixel_to_ray, project_points
from simtest.geometry.lights import Light, LightRig
from simtest.reconstruct.images import load_image
from simtest.reconstruct.isophote import extract_isophote
from simtest.reconstruct.lightaware import refine_isophote_points
from simtest.render import RendererUnavailable, render_scene
from simtest.resources import real_banner_path
from simtest.scene import load_scene
from simtest.simulate.analytic import phong_plane_image, plane_bp
from simtest.simulate.offset import rig_plane_image, specular_point

def synthetic_roi_image(size: int = 100, n_phong: float = 400.0):
    """One analytic Phong highlight (co-located light, tilted plane) in a ``size``-px square.

    Returns ``(image float64 (size, size), K, bp_uv, normal)``; the t = 0.1 isophote is about
    30 px across for the defaults.
    """

    f = 600.0
    K = np.array([[f, 0, size / 2 - 0.5], [0, f, size / 2 - 0.5], [0, 0, 1.0]])
    normal = np.array([0.0, 0.0, -1.0])
    img = phong_plane_image(K, (size, size), normal, 50.0, n_phong)
    bp = project_points(plane_bp(normal, 50.0), K)
    return img, K, bp, normal


def synthetic_frame(shape=(1080, 1350), n_highlights: int = 10, seed: int = 0, n_saturated: int = 2):
    """An RGB uint8 frame with ``n_highlights`` analytic Phong highlights on a dark background.

    Each highlight is the co-located Phong image of a plane facing the camera along the ray of
    its BP (so its BP is where it is placed), exponent n in [300, 500] (t = 0.1 isophote about
    60 to 80 px across at f = 600 px), peak 200 to 250; the first ``n_saturated`` are clipped
    (peak 320 before clipping at 255). The background is 5 to 15 (a smooth gradient), below the
    t = 0.1 level of every highlight. Randomness: ``SeedSequence([seed, k])`` per highlight.

    Returns
    -------
    frame : ndarray of shape (H, W, 3), uint8
    K : ndarray of shape (3, 3)
        f = 600 px, principal point at the centre.
    bps : ndarray of shape (n_highlights, 2)
        Where the BPs were placed (u, v), px.
    """

    h, w = shape
    f = 600.0
    K = np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1.0]])
    vv, uu = np.mgrid[0:h, 0:w]
    acc = 5.0 + 10.0 * (uu / w) * (vv / h)
    cols = 5
    rows = (n_highlights + cols - 1) // cols
    bps = []
    win = 160
    for k in range(n_highlights):
        rng = np.random.default_rng(np.random.SeedSequence([seed, k]))
        gr, gc = divmod(k, cols)
        u0 = (gc + 0.5) * w / cols + rng.uniform(-30, 30)
        v0 = (gr + 0.5) * h / rows + rng.uniform(-30, 30)
        normal = -pixel_to_ray(np.array([u0, v0]), K)
        r0, c0 = int(v0) - win // 2, int(u0) - win // 2
        Kw = K.copy()
        Kw[0, 2] -= c0
        Kw[1, 2] -= r0
        n_phong = rng.uniform(300.0, 500.0)
        patch = phong_plane_image(Kw, (win, win), normal, 50.0, n_phong)
        peak = 320.0 if k < n_saturated else rng.uniform(200.0, 250.0)
        acc[r0 : r0 + win, c0 : c0 + win] += peak * patch
        bps.append((u0, v0))
    gray = np.clip(np.rint(acc), 0, 255).astype(np.uint8)
    return np.repeat(gray[:, :, None], 3, axis=2), K, np.array(bps)


def noisy_frame(sigma_rel: float = 0.02, seed: int = 12):
    """:func:`synthetic_frame` with Gaussian read noise of ``sigma_rel`` x 255 (rounded, clipped).

    Returns ``(frame (H, W, 3) uint8, K, bps)`` as :func:`synthetic_frame`; the noise is drawn
    from ``numpy.random.default_rng(seed)``, one value per pixel, the same in the three channels.
    """
    frame, K, bps = synthetic_frame()
    rng = np.random.default_rng(seed)
    noisy = frame[:, :, 0].astype(np.float64) + rng.normal(0.0, sigma_rel * 255.0, frame.shape[:2])
    gray = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    return np.repeat(gray[:, :, None], 3, axis=2), K, bps


#: The real frame of the bench: the Hyper-Kvasir banner (:func:`simtest.resources.real_banner_path`),
#: read from the source tree.
BANNER = real_banner_path()


def banner_frame():
    """The banner as RGB uint8 and an assumed pinhole (f = 140 px, principal point at the centre:
    the banner is 24 uncalibrated frames side by side); None if the source tree is not there."""
    return real_frame(BANNER)


def real_frame(path: Path):
    """A real frame of the source tree as RGB uint8 (read as ``simtest reconstruct`` reads it,
    :func:`~simtest.reconstruct.images.load_image`) and its assumed pinhole (f = 140 px, the
    principal point at the centre: the Hyper-Kvasir frames are uncalibrated); None if the file
    is not there (a wheel does not ship the tests)."""
    if not path.is_file():
        return None
    img = load_image(path)
    h, w = img.shape[:2]
    K = np.array([[140.0, 0, (w - 1) / 2], [0, 140.0, (h - 1) / 2], [0, 0, 1]])
    return img, K


#: The real 1350 x 1080 frame of the bench: :func:`banner_mosaic`.
MOSAIC_SHAPE = (1080, 1350)
#: The banner's frames are 280 x 280 px tiles, 8 across and 3 down.
BANNER_TILE_PX = 280


def banner_mosaic(shift_px: int = 0):
    """A real 1350 x 1080 RGB uint8 frame: the first 20 of the banner's 24 real 280 x 280 px
    endoscopy frames (row by row) laid out 5 across and 4 down (1400 x 1120 px, real pixels, no
    resampling), cropped to 1350 x 1080 from column ``shift_px`` (0 to 50: the frames of the
    bench's video move by it), with the banner's assumed pinhole (f = 140 px, principal point at
    the centre); None if the source tree is not there.

    No real 1350 x 1080 endoscopy frame ships with simtest (``docs/decisions/benchmarks.md``): this
    one holds the banner's content at the target size (about 640 components with the defaults,
    every one examined; :func:`video_first_frame`, the same frame through MJPG, has about 2900)."""
    got = banner_frame()
    if got is None:
        return None
    img, _ = got
    t = BANNER_TILE_PX
    tiles = [img[r * t : (r + 1) * t, c * t : (c + 1) * t] for r in range(3) for c in range(8)][:20]
    mosaic = np.concatenate([np.concatenate(tiles[5 * k : 5 * k + 5], axis=1) for k in range(4)], axis=0)
    h, w = MOSAIC_SHAPE
    if not 0 <= shift_px <= mosaic.shape[1] - w:
        raise ValueError(f"shift_px must be in [0, {mosaic.shape[1] - w}], got {shift_px}")
    frame = np.ascontiguousarray(mosaic[:h, shift_px : shift_px + w])
    K = np.array([[140.0, 0, (w - 1) / 2], [0, 140.0, (h - 1) / 2], [0, 0, 1]])
    return frame, K


def colonoscope_render(scene: str = "colonoscope_tube"):
    """A bundled endoscope scene rendered at seed 0 (a RenderResult), or None where Mitsuba cannot
    render; by default ``colonoscope_tube`` (the default ``colonoscope`` until the haustral colon
    replaced it: the reconstruct rows keep their input)."""
    try:
        return render_scene(load_scene(scene), seed=0)
    except RendererUnavailable:
        return None


def colonoscope_frame(res=None):
    """The bundled ``colonoscope_tube`` scene rendered at seed 0 (or ``res``, such a render): its 8-bit RGB
    video frame (1080, 1350, 3) and its camera model (C3VD's omnidirectional calibration); None
    where Mitsuba cannot render."""
    res = colonoscope_render() if res is None else res
    return None if res is None else (res.frame, res.camera)


#: The bench video: frames of :func:`banner_mosaic` moved by this many px from one to the next...
VIDEO_STEP_PX = 2
#: ... this many frames (24 MJPG frames, 50 px of movement).
VIDEO_FRAMES = 24


def bench_video_file(folder, n_frames: int = VIDEO_FRAMES, step_px: int = VIDEO_STEP_PX):
    """Write the bench video into ``folder``: ``n_frames`` frames of :func:`banner_mosaic` shifted
    by ``step_px`` more each (a slow pan over real content), 25 frames/s, Motion-JPEG in AVI
    (OpenCV's ``VideoWriter``, no codec outside OpenCV). Returns ``(path, K)``, or None without
    the source tree (the banner) or where OpenCV cannot write MJPG."""
    first = banner_mosaic(0)
    if first is None:
        return None
    frame, K = first
    h, w = frame.shape[:2]
    path = Path(folder) / "bench_video.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (w, h))
    if not writer.isOpened():
        return None
    try:
        for i in range(n_frames):
            img = frame if i == 0 else banner_mosaic(min(i * step_px, 50))[0]
            writer.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
    return path, K


def video_first_frame():
    """The first frame of the bench video (:func:`bench_video_file`) as the video path decodes it:
    :func:`banner_mosaic` written as Motion-JPEG and read back by OpenCV, RGB uint8 (1080, 1350, 3),
    with the mosaic's pinhole; None without the source tree or an MJPG codec.

    The JPEG's blocks and ringing turn the mosaic's 641 bright components into about 2900, every
    one examined: the bench's stand-in for a real 1350 x 1080 frame with thousands of components
    (none ships with simtest); the row's note names the count."""
    with tempfile.TemporaryDirectory() as tmp:
        made = bench_video_file(tmp, 1)
        if made is None:
            return None
        path, K = made
        cap = cv2.VideoCapture(str(path))
        try:
            ok, bgr = cap.read()
        finally:
            cap.release()
    if not ok:
        return None
    return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)), K



def synthetic_offset_highlight(size: int = 64, n_phong: float = 150.0):
    """One exact highlight of a plane lit 3 mm off the camera (light-aware bench input).

    Plane at 20 mm tilted 25 deg, f = 400 px, inverse-square falloff, the specular point at the
    centre of a ``size``-px square ROI; the t = 0.3 isophote is about 30 px across.

    Returns ``(roi float64 (size, size), K, bp_uv, rig, points (list of (N, 2)), isovalues)``.
    """
    t = np.radians(25.0)
    normal = np.array([np.sin(t), 0.0, -np.cos(t)])
    rig = LightRig((Light((3.0, 0.0, 0.0), 1.0, "inverse_square"),))
    X, _ = specular_point(normal, 20.0, rig.lights[0].position_mm)
    K = np.array([[400.0, 0, 0], [0, 400.0, 0], [0, 0, 1.0]])
    x = project_points(X, K)
    K[0, 2], K[1, 2] = (size - 1) / 2 - x[0] + 0.3, (size - 1) / 2 - x[1] - 0.2
    roi = rig_plane_image(K, (size, size), normal, 20.0, rig, n_phong)
    bp = project_points(X, K)
    isovalues = (0.3, 0.6)
    pts = [refine_isophote_points(roi, v * roi.max(), extract_isophote(roi, v * roi.max(), bp).points_uv)
           for v in isovalues]
    return roi, K, bp, rig, pts, isovalues


def synthetic_sphere_two_guides(size: int = 48, radius_mm: float = 12.0, depth_mm: float = 40.0,
                                n_phong: float = 60.0):
    """Both guides' highlights on an exact Phong sphere (curved-patch bench input, 8-bit).

    A sphere of ``radius_mm`` whose nearest point lies ``depth_mm`` down the optical axis, two guides
    4 mm either side of the lens (inverse-square falloff), f = 400 px, the ROI ``size`` px square about
    the axis. Each pixel's ray meets the sphere (nearest root); its value is the sum over the guides of
    ``max(0, r_v . l)^n (depth / |X - L|)^2``, ``r_v`` the view ray mirrored in the normal; scaled to
    200 at the brightest and rounded.

    Returns ``(roi float64 (size, size), K, bp_uv, rig)``.
    """
    rig = LightRig(tuple(Light((x, 0.0, 0.0), 1.0, "inverse_square") for x in (-4.0, 4.0)))
    c0 = (size - 1) / 2
    K = np.array([[400.0, 0, c0], [0, 400.0, c0], [0, 0, 1.0]])
    uu, vv = np.meshgrid(np.arange(float(size)), np.arange(float(size)))
    d = pixel_to_ray(np.column_stack([uu.ravel(), vv.ravel()]), K)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centre = np.array([0.0, 0.0, depth_mm + radius_mm])
    b = d @ centre
    t = b - np.sqrt(np.maximum(b * b - (centre @ centre - radius_mm**2), 0.0))
    X = d * t[:, None]
    n = (X - centre) / radius_mm
    mirror = d - 2.0 * (d * n).sum(axis=1, keepdims=True) * n  # the view ray reflected off the sphere
    img = np.zeros(len(d))
    for light in rig.lights:
        to_l = np.asarray(light.position_mm) - X
        dist = np.linalg.norm(to_l, axis=1)
        img += np.maximum((mirror * to_l).sum(axis=1) / dist, 0.0) ** n_phong * (depth_mm / dist) ** 2
    img = np.round(img.reshape(size, size) / img.max() * 200.0)
    bp = np.array(np.unravel_index(int(np.argmax(img)), img.shape)[::-1], dtype=np.float64)
    return img, K, bp, rig
