"""Branching, tapering vessel networks under the mucosa, as a texture of the surface's own 2D coordinates.

Each layer of :data:`VESSEL_LAYERS` is a forest grown by space colonisation (Runions, Lane &
Prusinkiewicz 2007, https://doi.org/10.2312/NPH/NPH07/063-070) on a square tile of the (u, v) plane, mm,
from roots (perforating vessels). Radii follow Murray's law, ``r_parent^3 = sum r_child^3`` with every tip
at one radius (Murray 1926, https://doi.org/10.1073/pnas.12.3.207). A layer is drawn as an anti-aliased
coverage map, blurred in proportion to its depth (light scattered above a buried absorber spreads its
shadow), and turned into a transmission ``1 - absorb_c * coverage``; deeper layers absorb less and more
evenly (Kienle et al. 1996, https://doi.org/10.1364/AO.35.001151). The layers multiply into one (H, W, 3)
texture of a tile :data:`TILE_MM` wide, repeated mirrored. Calibres follow the human colon's plexuses
(Skinner & O'Brien 1996, https://doi.org/10.1006/jsre.1996.0151); densities, steps and absorptions are
assumed, and ``simtest simreal`` compares the result with real frames.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

__all__ = ["VESSEL_LAYERS", "VESSEL_SEED_KEY", "TILE_MM", "TEXEL_MM", "SUPERSAMPLE", "BLUR_PER_DEPTH",
           "VesselLayer", "Network", "grow_network", "murray_radii", "coverage_map", "transmission_map"]

#: Stable key of the vessel stream: layer i grows from ``SeedSequence([seed, VESSEL_SEED_KEY, i])``,
#: ``seed`` the tissue's texture seed.
VESSEL_SEED_KEY = 0x7E55E1
#: Width of the square tile, mm: wider than the scenes' well-lit field (about 40 mm), so the repeat is rarely seen
TILE_MM = 64.0
#: Texel of the transmission texture, mm: finer than a pixel's footprint at working distances (0.1-0.3 mm)
TEXEL_MM = 0.04
#: Drawing raster per texel side (anti-aliasing: coverage is the mean of SUPERSAMPLE^2 sub-texels).
SUPERSAMPLE = 4
#: Gaussian sigma of a layer's blur per mm of depth (assumed: a buried absorber's shadow spreads about its depth)
BLUR_PER_DEPTH = 0.5


@dataclass(frozen=True)
class VesselLayer:
    """One plexus: depth, calibre, space-colonisation parameters (mm, per mm^2) and (R, G, B) absorption."""

    name: str
    depth_mm: float
    root_radius_mm: float
    step_mm: float  # growth step D
    influence_mm: float  # radius of influence d_i
    kill_mm: float  # kill distance d_k (> step: a node's own child kills its attraction points)
    attractors_per_mm2: float
    roots_per_mm2: float
    absorb: tuple[float, float, float]

    @property
    def blur_sigma_mm(self) -> float:
        """Gaussian sigma of the layer's blur, mm (:data:`BLUR_PER_DEPTH` times the depth)."""
        return BLUR_PER_DEPTH * self.depth_mm


#: The plexuses drawn, shallow to deep (sources in the module notes): mucosal venules, dark red; submucosal
#: vessels, fainter and grey-blue.
VESSEL_LAYERS = (
    VesselLayer("mucosal", depth_mm=0.15, root_radius_mm=0.075, step_mm=0.25, influence_mm=1.5, kill_mm=0.35,
                attractors_per_mm2=2.0, roots_per_mm2=1.0 / 16.0, absorb=(0.25, 0.55, 0.45)),
    VesselLayer("submucosal", depth_mm=0.6, root_radius_mm=0.25, step_mm=0.6, influence_mm=4.0, kill_mm=0.9,
                attractors_per_mm2=0.15, roots_per_mm2=1.0 / 256.0, absorb=(0.30, 0.26, 0.14)),
)


@dataclass(frozen=True)
class Network:
    """A forest: node positions (N, 2) mm in the tile, and each node's parent index (-1 for a root, else smaller)."""

    nodes: np.ndarray
    parent: np.ndarray


def grow_network(rng: np.random.Generator, layer: VesselLayer, tile_mm: float = TILE_MM,
                 max_steps: int = 2000) -> Network:
    """Grow one layer's forest by space colonisation on ``[0, tile_mm]^2``.

    Parameters
    ----------
    rng : numpy.random.Generator
        The layer's stream (attraction points and roots only).
    layer : VesselLayer
    tile_mm : float
        Side of the square tile, mm.
    max_steps : int
        Cap on growth steps.

    Returns
    -------
    Network
    """
    area = tile_mm * tile_mm
    attr = rng.uniform(0.0, tile_mm, size=(rng.poisson(layer.attractors_per_mm2 * area), 2))
    roots = rng.uniform(0.0, tile_mm, size=(max(1, rng.poisson(layer.roots_per_mm2 * area)), 2))
    nodes = [roots]
    parent = [np.full(len(roots), -1, dtype=np.int64)]
    all_nodes = roots
    seen = set(map(tuple, np.round(roots / (0.1 * layer.step_mm)).astype(np.int64).tolist()))
    # each attraction point's nearest node so far: one small tree of the new nodes per step
    best_d = np.full(len(attr), np.inf)
    best_k = np.zeros(len(attr), dtype=np.int64)
    new, first = roots, 0
    for _ in range(max_steps):
        d_new, k_new = cKDTree(new).query(attr, distance_upper_bound=layer.influence_mm)
        closer = d_new < best_d
        best_d[closer], best_k[closer] = d_new[closer], k_new[closer] + first
        live = ~(d_new <= layer.kill_mm)  # attraction points within the kill distance of a new node go
        attr, best_d, best_k = attr[live], best_d[live], best_k[live]
        pulled = np.isfinite(best_d)
        if not pulled.any():
            break
        a, k = attr[pulled], best_k[pulled]
        u = (a - all_nodes[k]) / np.maximum(best_d[pulled], 1e-12)[:, None]
        acc = np.zeros_like(all_nodes)
        np.add.at(acc, k, u)
        grow = np.unique(k)
        d = acc[grow]
        norm = np.linalg.norm(d, axis=1)
        ok = norm > 1e-9  # attraction points in opposite directions cancel: no growth
        grow, d = grow[ok], d[ok] / norm[ok, None]
        cand = all_nodes[grow] + layer.step_mm * d
        # a node pulled the same way as last step would grow the same child again: keep new sites only
        key = np.round(cand / (0.1 * layer.step_mm)).astype(np.int64).tolist()
        fresh = np.array([tuple(q) not in seen for q in key], dtype=bool)
        if not fresh.any():
            break
        seen.update(tuple(q) for q, f in zip(key, fresh) if f)
        new, first = cand[fresh], len(all_nodes)
        nodes.append(new)
        parent.append(grow[fresh].astype(np.int64))
        all_nodes = np.concatenate([all_nodes, new])
    return Network(np.concatenate(nodes), np.concatenate(parent))


def murray_radii(net: Network, root_radius_mm: float) -> np.ndarray:
    """Radius of every node, mm, by Murray's law (module notes): ``r^3`` proportional to the
    number of tips downstream, each tree's root at ``root_radius_mm``.

    Returns
    -------
    ndarray of shape (N,)
        ``r[p]^3 = sum of r[c]^3 over p's children c`` at every node with children.
    """
    n = len(net.parent)
    has_child = np.zeros(n, dtype=bool)
    has_child[net.parent[net.parent >= 0]] = True
    tips = (~has_child).astype(np.float64)
    for i in range(n - 1, -1, -1):  # children have larger indices than their parents
        p = net.parent[i]
        if p >= 0:
            tips[p] += tips[i]
    root = np.arange(n)
    for i in range(n):  # each node's root (parents come first)
        if net.parent[i] >= 0:
            root[i] = root[net.parent[i]]
    return root_radius_mm * np.cbrt(tips / tips[root])


def coverage_map(net: Network, radii: np.ndarray, tile_mm: float = TILE_MM, texel_mm: float = TEXEL_MM,
                 sigma_mm: float = 0.0) -> np.ndarray:
    """Anti-aliased coverage of the network's vessels on the tile's texels, blurred.

    Each segment (node to parent) is drawn with the child's radius and round caps on a raster
    :data:`SUPERSAMPLE` times finer than the texels, averaged down, then blurred by a Gaussian of
    ``sigma_mm`` (mirrored at the tile's edges, as the texture repeats).

    Returns
    -------
    ndarray of shape (H, W), float32
        Coverage in [0, 1]; row ``i``, column ``j`` is the texel centred at
        ``(u, v) = ((j + 0.5) texel_mm, (i + 0.5) texel_mm)``.
    """
    n_px = int(round(tile_mm / texel_mm))
    fine = np.zeros((n_px * SUPERSAMPLE, n_px * SUPERSAMPLE), np.uint8)
    scale = SUPERSAMPLE / texel_mm
    shift = 4  # cv2's sub-pixel bits: endpoints to 1/16 of a sub-texel
    child = np.nonzero(net.parent >= 0)[0]
    a = np.round(net.nodes[child] * scale * (1 << shift) - 0.5 * (1 << shift)).astype(np.int64)
    b = np.round(net.nodes[net.parent[child]] * scale * (1 << shift) - 0.5 * (1 << shift)).astype(np.int64)
    thick = np.maximum(1, np.round(2.0 * radii[child] * scale)).astype(np.int64)
    for p0, p1, w in zip(a.tolist(), b.tolist(), thick.tolist()):
        cv2.line(fine, tuple(p0), tuple(p1), 255, int(w), cv2.LINE_8, shift)
    cov = cv2.resize(fine, (n_px, n_px), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    if sigma_mm > 0.0:
        cov = cv2.GaussianBlur(cov, (0, 0), sigma_mm / texel_mm, borderType=cv2.BORDER_REFLECT)
    return cov


@functools.lru_cache(maxsize=4)
def transmission_map(seed: int, layers: tuple[VesselLayer, ...] = VESSEL_LAYERS) -> np.ndarray:
    """The vessel texture of a texture seed: ``prod over layers of (1 - absorb_c * coverage)``.

    Parameters
    ----------
    seed : int
        The tissue's texture seed; layer ``i`` grows from
        ``SeedSequence([seed, VESSEL_SEED_KEY, i])``.
    layers : tuple of VesselLayer

    Returns
    -------
    ndarray of shape (H, W, 3), float32, read-only
        Per-channel transmission in [0, 1] over the tile (texels as :func:`coverage_map`).
    """
    out = None
    for i, layer in enumerate(layers):
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), VESSEL_SEED_KEY, i]))
        net = grow_network(rng, layer)
        cov = coverage_map(net, murray_radii(net, layer.root_radius_mm), sigma_mm=layer.blur_sigma_mm)
        t = 1.0 - cov[..., None] * np.asarray(layer.absorb, dtype=np.float32)
        out = t if out is None else out * t
    out = np.ascontiguousarray(out, dtype=np.float32)
    out.flags.writeable = False
    return out
