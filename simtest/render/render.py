"""Render a scene spec with Mitsuba 3: image, sensor image, per-pixel and per-highlight truth.

The ``simtest_gt`` integrator (:mod:`simtest.render.integrator`) traces each camera ray once; the colour
channels carry the full (R), specular-only (G) and diffuse-only (B) images (:mod:`simtest.render.phong`),
alpha the coverage, the AOVs shading normals and positions. All outputs are camera-frame; meshes are built
once in their world frame and a new view moves the sensor (:func:`simtest.render.scene_load._mitsuba_scene`).
Endoscope scenes go to :mod:`~simtest.render.rig_render`.
"""

from __future__ import annotations

import os
import resource

import numpy as np

from simtest._io import OutputFolderError
from simtest._lazy import require
from simtest.constants import MAX_SEED
from simtest.render.endoscope import uses_endoscope
from simtest.render.mitsuba_dict import cam_to_world_matrix, intrinsics_matrix, light_position_cam
from simtest.render.outputs import RENDER_FILES, TISSUE_COVERAGE, RenderResult, write_render
from simtest.render.rig_render import _highlights, _render_endoscope, _sensor_image, visible_highlights
from simtest.render.scene_load import (_RENDER_LOCK, RenderInputError, RendererUnavailable, _mitsuba_scene,
                                      choose_variant)
from simtest.scene.spec import SceneSpec

__all__ = ["MAX_SEED", "RenderResult", "RendererUnavailable", "RenderInputError", "check_film_fits",
           "visible_highlights", "choose_variant", "render_scene", "write_render", "RENDER_FILES", "OutputFolderError"]

#: Bytes of memory one film pixel needs during a render, whatever the spp: Mitsuba's peak (measured about
#: 160 B/px on a plane) plus the kept float32 maps (about 90 B/px), with a margin for other shapes.
BYTES_PER_PIXEL = 400
#: Memory a render needs besides its film (the Mitsuba/LLVM runtime, measured ~300 MB).
BASE_BYTES = 512 * 2**20


def available_memory_bytes() -> int | None:
    """Memory a new allocation can get: MemAvailable, capped by RLIMIT_AS / RLIMIT_DATA; None when unknown."""
    avail: int | None = None
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except OSError:
        avail = None
    for lim in (resource.RLIMIT_AS, resource.RLIMIT_DATA):
        soft, _ = resource.getrlimit(lim)
        if soft != resource.RLIM_INFINITY:
            used = 0
            if lim == resource.RLIMIT_AS:
                try:
                    with open("/proc/self/statm", encoding="ascii") as fh:
                        used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
                except OSError:
                    used = 0
            room = max(int(soft) - used, 0)
            avail = room if avail is None else min(avail, room)
    return avail


def check_film_fits(spec: SceneSpec) -> None:
    """Raise :class:`RenderInputError` if ``BASE_BYTES + BYTES_PER_PIXEL * W * H`` exceeds the available memory."""
    W, H = spec.camera.width_px, spec.camera.height_px
    need = BASE_BYTES + BYTES_PER_PIXEL * W * H
    avail = available_memory_bytes()
    if avail is not None and need > avail:
        raise RenderInputError(
            f"{spec.source}: camera.width_px x camera.height_px: a {W} x {H} render needs about "
            f"{need / 2**30:.1f} GiB of memory, more than the {avail / 2**30:.1f} GiB available")


def render_scene(spec: SceneSpec, *, seed: int | None = None, variant: str | None = None) -> RenderResult:
    """Render ``spec`` and return the images with their ground truth.

    Parameters
    ----------
    spec : SceneSpec
    seed : int, optional
        Root seed of the sampler, the sensor noise and the light draw (default ``spec.render.seed``); the
        same seed gives bit-identical outputs.
    variant : str, optional
        Mitsuba variant; None uses ``spec.render.variant`` ("auto": CUDA if usable, else LLVM).

    Returns
    -------
    RenderResult

    Raises
    ------
    ValueError
        If ``seed`` is outside [0, :data:`MAX_SEED`].
    RendererUnavailable
        If Mitsuba cannot run the variant here.
    RenderInputError
        If the mesh file is not a readable PLY with k1/k2, a face indexes a missing vertex, or the film would
        not fit in memory.
    simtest.simulate.truth.HighlightTruthError
        If an analytic sphere's or cylinder's BP cannot be solved for (camera or light inside the surface).

    Notes
    -----
    With ``light.falloff = "cancel"`` the Phong BSDF multiplies by the squared light distance per sample;
    for the microfacet BSDFs the image is multiplied per pixel by that of the pixel's mean surface point.
    """
    mi = require("mitsuba")
    seed = spec.render.seed if seed is None else int(seed)
    if not 0 <= seed <= MAX_SEED:
        raise ValueError(f"render seed {seed} is out of range: must be in [0, 2^31 - 1 = {MAX_SEED}] "
                         "(Mitsuba's samplers take 32-bit seeds; the range of render.seed in scene files)")
    check_film_fits(spec)
    variant = choose_variant(variant or spec.render.variant)
    if uses_endoscope(spec):
        with _RENDER_LOCK:
            return _render_endoscope(spec, seed, variant)
    light_pos = light_position_cam(spec.light, seed)
    # cached scenes are updated in place: one render at a time, from the update to the last ray cast
    with _RENDER_LOCK:
        scene, pose = _mitsuba_scene(spec, light_pos, variant)
        image = mi.render(scene, spp=spec.render.spp, seed=seed)
        # a view of Dr.Jit's host memory (only new arrays derived from it are returned)
        out = np.asarray(image, dtype=np.float32)
        alpha = out[..., 3]
        nn, pp = out[..., 4:7], out[..., 7:10]
        nlen = np.sqrt(np.einsum("ijk,ijk->ij", nn, nn))
        mask = (alpha >= 1.0) & (nlen > 0)
        linear, specular = out[..., 0].copy(), out[..., 1].copy()
        if spec.light.falloff == "cancel" and spec.material.model != "phong":
            cov = np.where(alpha > 0, alpha, 1.0)[..., None]
            pos_mean = pp / cov  # partially covered pixels: mean over the samples that hit
            d2 = np.sum((pos_mean - light_pos.astype(np.float32)) ** 2, axis=-1)
            d2 = np.where(alpha > 0, d2, 0.0).astype(np.float32)
            linear *= d2
            specular *= d2
        # unit normals facing the camera (n . ray < 0), NaN outside the mask
        sign = np.where(np.einsum("ijk,ijk->ij", nn, pp) > 0, -1.0, 1.0).astype(np.float32)
        scale = np.where(mask, sign / np.where(mask, nlen, 1.0), np.float32(np.nan))
        normals = nn * scale[..., None]
        position = np.where(mask[..., None], pp, np.float32(np.nan))
        depth = position[..., 2].copy()
        distance = np.sqrt(np.einsum("ijk,ijk->ij", position, position))  # |mean position|

        K = intrinsics_matrix(spec.camera)
        if spec.geometry.triangulated:
            res = {"normals_raw": np.where(mask[..., None], normals, 0.0),
                   "position_raw": np.where(mask[..., None], position, 0.0), "mask": mask}
        else:
            res = {}
        highlights = visible_highlights(_highlights(spec, res, light_pos, K, scene, pose), specular)
    sensor, video = _sensor_image(linear, None, spec, seed, tissue=alpha >= TISSUE_COVERAGE)
    return RenderResult(linear=linear, sensor=sensor, specular=specular, normals=normals, depth=depth,
                        distance=distance, position=position, mask=mask, coverage=alpha.astype(np.float32),
                        K=K, cam_to_world=cam_to_world_matrix(spec.camera), light_pos=light_pos,
                        highlights=highlights, variant=variant, seed=seed, spec=spec, video=video)
