"""The paper's synthetic protocol, ``paper`` (Makki and Bartoli, section 3.1 and figure 2).

1. **Texture.** A ``T x T`` texture of the plane ``z = 0`` by eq. 1
   (:func:`simtest.specular.phong_intensity`) for a viewer ``V = (0, 0, V_Z)`` and a light
   ``L = V + epsilon (cos a, sin a, b)``, ``a ~ U[0, 2 pi)``, ``b ~ U[-0.5, 0.5]``; lengths in
   texture pixels. Texture pixel ``(u, v)`` is the plane point ``(x0 + u - T/2, y0 - (v - T/2), 0)``,
   the window centred on the BP when ``window_at_bp``.
2. **Homography.** A pinhole camera ``K = [[f, 0, M/2], [0, f, M/2], [0, 0, 1]]``, ``f = M``, looks
   at the window centre from ``D = V_Z`` (the paper's "camera to scene plane distance") along a
   direction tilted by ``theta`` about the plane's x axis; the image is
   ``cv2.warpPerspective(texture, H)``, ``H = K [r1 r2 t] A`` [3], bilinear, zero outside.
3. **Noise.** White Gaussian noise of standard deviation ``sigma`` (fraction of ``c = 1``), no
   clipping, no quantisation.
4. **Smoothing and normalisation.** ``cv2.GaussianBlur`` of standard deviation ``smoothing_px``
   (reflected border), then division by the smoothed intensity at the BP pixel.

For ``theta != 0`` the camera is not the viewer (this is the published protocol, not a co-located
endoscope). The ground-truth normal is ``(0, sin theta, -cos theta)`` in the slanted camera's
OpenCV frame. :meth:`PaperSimulator.sample` draws ``a``, ``b`` (always) then the noise image.

References
----------
.. [1] K. Makki, A. Bartoli, "Normal Reconstruction from Specularity in the Endoscopic Setting",
       section 3.1 (synthetic data, steps 1-4), eq. 1, figures 2 and 3.
.. [2] B. T. Phong, "Illumination for computer generated pictures", CACM 18(6), 1975.
       https://doi.org/10.1145/360825.360839
.. [3] R. Hartley, A. Zisserman, Multiple View Geometry, 2nd ed., 2003, sec. 8.1.
       https://doi.org/10.1017/CBO9780511811685
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Annotated

import cv2
import numpy as np
from pydantic import Field
from pydantic.dataclasses import dataclass as pydantic_dataclass

from simtest._config import CONFIG, Bool, Int, Num
from simtest.constants import gaussian_radius_px, smooth_block_px
from simtest.specular import phong_intensity

__all__ = ["PaperParams", "PaperSample", "PaperSimulator", "paper_homography"]


@pydantic_dataclass(frozen=True, config=CONFIG)
class PaperParams:
    """Parameters of the ``paper`` protocol; the defaults are the paper's (its figure 3).

    Attributes
    ----------
    image_px : int
        M, the side of the square image (and of the texture unless ``texture_px``). Paper: 406.
    viewer_height_px : float
        V_Z, height of the viewer above the plane, texture pixels. Paper: 1000.
    n : float
        Phong roughness exponent (eq. 1). Paper: 50 (100 in the epsilon sweep).
    c : float
        Phong scale (eq. 1); the intensity range. 1.
    sigma : float
        Noise standard deviation, fraction of the intensity range. Paper: 0.05.
    theta_deg : float
        Angle between the plane normal and the camera axis, degrees in [0, 90). Paper: 58.
    epsilon_px : float
        Light offset scale, texture pixels, >= 0. Paper: 0.
    smoothing_px : float
        Standard deviation of the Gaussian smoothing, image pixels (0: none); not stated in the
        paper, 2 px is our choice.
    focal_px : float or None
        f; None: ``image_px``.
    camera_distance_px : float or None
        D, slanted camera to window centre, texture pixels; None: ``viewer_height_px``.
    texture_px : int or None
        T, side of the texture; None: ``image_px``.
    window_at_bp : bool
        Centre the texture window (and so the image) at the BP (the paper's epsilon sweep).

    Raises
    ------
    pydantic.ValidationError
        On construction, if a value is not of its field's type or out of its range.
    """

    image_px: Annotated[Int, Field(ge=8, le=8192)] = 406
    viewer_height_px: Annotated[Num, Field(gt=0)] = 1000.0
    n: Annotated[Num, Field(gt=0)] = 50.0
    c: Annotated[Num, Field(gt=0)] = 1.0
    sigma: Annotated[Num, Field(ge=0)] = 0.05
    theta_deg: Annotated[Num, Field(ge=0, lt=90)] = 58.0
    epsilon_px: Annotated[Num, Field(ge=0)] = 0.0
    smoothing_px: Annotated[Num, Field(ge=0)] = 2.0
    focal_px: Annotated[Num, Field(gt=0)] | None = None
    camera_distance_px: Annotated[Num, Field(gt=0)] | None = None
    texture_px: Annotated[Int, Field(ge=8)] | None = None
    window_at_bp: Bool = True

    @property
    def focal(self) -> float:
        """f, px (``focal_px`` or ``image_px``)."""
        return float(self.image_px if self.focal_px is None else self.focal_px)

    @property
    def distance(self) -> float:
        """D, camera to window-centre distance, texture px (``camera_distance_px`` or V_Z)."""
        return float(self.viewer_height_px if self.camera_distance_px is None else self.camera_distance_px)

    @property
    def texture(self) -> int:
        """T, the texture side in pixels."""
        return int(self.image_px if self.texture_px is None else self.texture_px)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Names of the parameters (the keys a sweep may vary).

        Returns
        -------
        tuple of str
            The dataclass field names, in declaration order.
        """
        return tuple(f.name for f in dataclasses.fields(cls))


@dataclass(frozen=True)
class PaperSample:
    """One realisation of the ``paper`` protocol.

    Attributes
    ----------
    image : ndarray of shape (M, M), float32
        Smoothed image normalised to 1 at the BP; rows = v, columns = u.
    K : ndarray of shape (3, 3)
        Intrinsics of the slanted camera, px (principal point M/2).
    bp_px : ndarray of shape (2,)
        The true BP in the image, (u, v), px.
    normal : ndarray of shape (3,)
        Ground-truth plane normal, OpenCV camera frame, unit, facing the camera.
    light_px : ndarray of shape (3,)
        Light position in the plane frame (texture pixels).
    bp_value : float
        The smoothed intensity at the BP that the image was divided by.
    clean : ndarray of shape (M, M), float32
        The noiseless warped image, shared between realisations when the light is fixed: do not modify.
    region : tuple of int or None
        ``(row0, row1, col0, col1)`` asked of :meth:`PaperSimulator.sample` (``image`` is 0 outside
        the box holding it and the BP's 2 x 2 pixels); None for the whole image.
    """

    image: np.ndarray
    K: np.ndarray
    bp_px: np.ndarray
    normal: np.ndarray
    light_px: np.ndarray
    bp_value: float
    clean: np.ndarray
    region: tuple[int, int, int, int] | None = None


def paper_homography(params: PaperParams, window_centre=(0.0, 0.0)):
    """Homography from texture pixels to image pixels, with the camera that defines it (module step 2).

    Parameters
    ----------
    params : PaperParams
        The protocol parameters.
    window_centre : array_like of shape (2,)
        Plane point (x, y), texture pixels, at the texture centre; the camera looks at it.

    Returns
    -------
    H : ndarray of shape (3, 3)
        Texture pixel (u, v, 1) -> image pixel (u, v, 1), ``H[2, 2] = 1``.
    K : ndarray of shape (3, 3)
        ``[[f, 0, M/2], [0, f, M/2], [0, 0, 1]]``, px.
    R : ndarray of shape (3, 3)
        Plane-frame to camera-frame rotation (rows: the OpenCV camera axes in the plane frame).
    C : ndarray of shape (3,)
        Camera centre in the plane frame, texture pixels.
    """
    M, f, T = params.image_px, params.focal, params.texture
    x0, y0 = float(window_centre[0]), float(window_centre[1])
    K = np.array([[f, 0.0, M / 2.0], [0.0, f, M / 2.0], [0.0, 0.0, 1.0]])
    # the slanted camera: R's rows are its axes in the plane frame, C its centre
    theta = math.radians(params.theta_deg)
    z_cam = np.array([0.0, -math.sin(theta), -math.cos(theta)])  # optical axis, toward the window centre
    x_cam = np.array([1.0, 0.0, 0.0])
    R = np.stack([x_cam, np.cross(z_cam, x_cam), z_cam])  # y = (0, -cos, sin): image down
    C = np.array([x0, y0, 0.0]) - params.distance * z_cam
    t = -R @ C
    P_plane = K @ np.column_stack([R[:, 0], R[:, 1], t])  # plane (x, y, 1) -> image
    A = np.array([[1.0, 0.0, x0 - T / 2.0], [0.0, -1.0, y0 + T / 2.0], [0.0, 0.0, 1.0]])
    H = P_plane @ A
    return H / H[2, 2], K, R, C


def mirror_point(V, L) -> np.ndarray:
    """The BP on the plane z = 0: where the mirror ray from the light reaches the viewer.

    Parameters
    ----------
    V : array_like of shape (3,)
        Viewer position, plane frame (texture pixels), ``V_Z > 0``.
    L : array_like of shape (3,)
        Light position, plane frame, ``L_Z > 0``.

    Returns
    -------
    ndarray of shape (2,)
        ``(x, y)`` where beta = 0 in eq. 1, so ``I = c`` (the maximum); for ``L = V`` it is
        ``(V_X, V_Y)``. Not checked: ``V_Z + L_Z = 0`` divides by zero.
    """
    V = np.asarray(V, dtype=np.float64)
    L = np.asarray(L, dtype=np.float64)
    # The mirror ray from (L_x, L_y, -L_z) to V meets z = 0 at the fraction s of the way.
    s = L[2] / (V[2] + L[2])
    return L[:2] + s * (V[:2] - L[:2])


#: Column alignment (and extra reach) of the region a sample is smoothed in, so that OpenCV computes
#: each column in the same kind of block (SIMD or scalar) as over the whole image.
SMOOTH_ALIGN = smooth_block_px(np.dtype(np.float32).itemsize)


@dataclass
class PaperSimulator:
    """Draws realisations of the ``paper`` protocol; the noiseless image is computed once when the
    light is fixed (``epsilon = 0``), so only noise, smoothing and normalisation run per sample.

    Parameters
    ----------
    params : PaperParams
        Validated protocol parameters.

    Examples
    --------
    >>> sim = PaperSimulator(PaperParams(sigma=0.0, theta_deg=0.0))
    >>> s = sim.sample(np.random.default_rng(0))
    >>> s.image.shape, float(s.image[203, 203])
    ((406, 406), 1.0)
    """

    params: PaperParams
    _clean: np.ndarray | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        p = self.params
        self.V = np.array([0.0, 0.0, p.viewer_height_px])
        T = p.texture
        g = np.arange(T, dtype=np.float64) - T / 2.0
        gx, gy = np.meshgrid(g, -g)  # plane offsets from the window centre
        self._offsets = np.stack([gx, gy], axis=-1)  # (T, T, 2): points (x, y) of the plane z = 0
        if p.epsilon_px == 0.0:
            self._clean, self._geom = self._render_clean(self.V)

    def _render_clean(self, L: np.ndarray):
        """Texture for light L (window placed per ``window_at_bp``), warped to the image."""
        p = self.params
        bp_plane = mirror_point(self.V, L)
        centre = bp_plane if p.window_at_bp else np.zeros(2)
        texture = phong_intensity(self._offsets, self.V, L, p.n, p.c, origin=centre[:2]).astype(np.float32)
        H, K, R, C = paper_homography(p, centre)
        M = p.image_px
        image = cv2.warpPerspective(texture, H, (M, M), flags=cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        # BP in the image: project the plane BP with the camera (exactly M/2 when window_at_bp).
        uvw = K @ (R @ (np.array([bp_plane[0], bp_plane[1], 0.0]) - C))
        bp_px = uvw[:2] / uvw[2]
        normal = R @ np.array([0.0, 0.0, 1.0])  # camera above the plane: +z faces it
        return image, (K, bp_px, normal)

    def light(self, rng: np.random.Generator) -> np.ndarray:
        """Draw the light position ``L = V + epsilon (cos a, sin a, b)`` (paper section 3.1).

        Parameters
        ----------
        rng : numpy.random.Generator
            The realisation's generator; ``a ~ U[0, 2 pi)`` then ``b ~ U[-0.5, 0.5)`` are always
            drawn, even for ``epsilon = 0``.

        Returns
        -------
        ndarray of shape (3,)
            L in the plane frame, texture pixels.
        """
        a = rng.uniform(0.0, 2.0 * math.pi)
        b = rng.uniform(-0.5, 0.5)
        return self.V + self.params.epsilon_px * np.array([math.cos(a), math.sin(a), b])

    @property
    def fixed(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(clean, bp_px)`` when the light is fixed (``epsilon = 0``), None when it moves."""
        return None if self._clean is None else (self._clean, self._geom[1])

    def sample(self, rng: np.random.Generator, region=None) -> PaperSample:
        """One realisation: light draw, noise, smoothing, normalisation at the BP.

        Parameters
        ----------
        rng : numpy.random.Generator
            The realisation's own generator (derive it from a SeedSequence).
        region : callable, optional
            ``region(clean, bp_px) -> (row0, row1, col0, col1)`` (half-open, px): the only pixels
            the caller reads (the reconstruction's ROI). The noise is the whole image's random
            stream in raster order, drawn through the last row that the smallest box holding
            the region and the BP's 2 x 2 pixels (which the normalisation reads), grown by the
            smoothing kernel's radius, reads; it is scaled, smoothed and normalised only in that
            box: there the image is the same bits as without ``region`` (each smoothed pixel
            reads the pixels within the radius, and OpenCV reflects at the image's own sides),
            elsewhere it is 0. The generator is left after that row's noise (after the whole
            image's without ``region``). Default: the whole image. The region asked is the
            sample's ``region``.

        Returns
        -------
        PaperSample

        Raises
        ------
        FloatingPointError
            If the smoothed intensity at the BP is not positive (cannot normalise).
        """
        p = self.params
        L = self.light(rng)
        clean, (K, bp_px, normal) = (self._clean, self._geom) if self._clean is not None else self._render_clean(L)
        M = p.image_px
        asked = None if region is None else tuple(int(v) for v in region(clean, bp_px))
        box = (0, M, 0, M) if asked is None else _read_box(asked, bp_px, M)
        r0, r1, c0, c1 = box
        # smoothed in the box grown by the kernel's radius, columns aligned on SMOOTH_ALIGN
        o0, o1, q0, q1 = 0, M, 0, M
        if p.smoothing_px > 0:
            pad = gaussian_radius_px(p.smoothing_px) + 1
            o0, o1 = max(0, r0 - pad), min(M, r1 + pad)
            q0 = max(0, c0 - pad) // SMOOTH_ALIGN * SMOOTH_ALIGN
            q1 = c1 + pad + SMOOTH_ALIGN
            q1 = M if q1 > M - SMOOTH_ALIGN else q1
        elif box != (0, M, 0, M):
            o0, o1, q0, q1 = box
        if p.sigma > 0:
            # clean + sigma * noise in float32; the raster-order noise drawn through the last row read
            image = rng.standard_normal((o1, M), dtype=np.float32)[o0:o1, q0:q1]
            image *= np.float32(p.sigma)
            image += clean[o0:o1, q0:q1]
        else:
            image = clean[o0:o1, q0:q1].copy()
        if p.smoothing_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), sigmaX=p.smoothing_px, sigmaY=p.smoothing_px,
                                     borderType=cv2.BORDER_REFLECT)
        if box != (0, M, 0, M):
            full = np.zeros((M, M), np.float32)
            full[r0:r1, c0:c1] = image[r0 - o0 : r1 - o0, c0 - q0 : c1 - q0]
            image = full
        value = _bilinear(image, bp_px)
        if not value > 0:
            raise FloatingPointError(f"smoothed intensity at the BP {bp_px.tolist()} is {value}")
        image[r0:r1, c0:c1] /= np.float32(value)  # image is this realisation's own array here
        return PaperSample(image=image, K=K.copy(), bp_px=bp_px.copy(), normal=normal.copy(),
                           light_px=L, bp_value=float(value), clean=clean, region=asked)


def _read_box(region, bp_px: np.ndarray, M: int) -> tuple[int, int, int, int]:
    """Smallest box (row0, row1, col0, col1) in the M x M image holding ``region`` and the BP's 2 x 2 pixels."""
    r0, r1, c0, c1 = (int(v) for v in region)
    u = min(max(float(bp_px[0]), 0.0), M - 1.0)
    v = min(max(float(bp_px[1]), 0.0), M - 1.0)
    cu, rv = int(math.floor(u)), int(math.floor(v))
    return (max(0, min(r0, rv)), min(M, max(r1, rv + 2)), max(0, min(c0, cu)), min(M, max(c1, cu + 2)))


def _bilinear(image: np.ndarray, uv: np.ndarray) -> float:
    u, v = float(uv[0]), float(uv[1])
    h, w = image.shape
    u = min(max(u, 0.0), w - 1.0)
    v = min(max(v, 0.0), h - 1.0)
    c0, r0 = int(math.floor(u)), int(math.floor(v))
    c1, r1 = min(c0 + 1, w - 1), min(r0 + 1, h - 1)
    fu, fv = u - c0, v - r0
    top = (1 - fu) * image[r0, c0] + fu * image[r0, c1]
    bot = (1 - fu) * image[r1, c0] + fu * image[r1, c1]
    return float((1 - fv) * top + fv * bot)

