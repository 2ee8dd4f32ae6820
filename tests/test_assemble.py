"""The ``merged`` test of the assembly (simtest.reconstruct.assemble.count_enclosed)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.reconstruct.assemble import count_enclosed
from simtest.reconstruct.isophote import polygon_contains


def _star(rng, n_vertices, centre, radius):
    """A star-shaped (possibly self-touching) closed polygon (n, 2)."""
    ang = np.sort(rng.uniform(0, 2 * np.pi, n_vertices))
    rad = rng.uniform(1.0, radius, n_vertices)
    return np.column_stack([centre[0] + rad * np.cos(ang), centre[1] + rad * np.sin(ang)])


def _enclosed_by_definition(poly, points, skip):
    """The points but row ``skip`` within the polygon's bounding box (bounds included) that
    polygon_contains puts inside."""
    near = np.all((points >= poly.min(axis=0)) & (points <= poly.max(axis=0)), axis=1)
    if skip >= 0:
        near[skip] = False
    return int(np.count_nonzero(polygon_contains(poly, points[near]))) if near.any() else 0


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 6), st.integers(0, 60))
def test_each_polygon_counts_the_points_in_its_box_inside_by_the_even_odd_rule(seed, n_polys, n_points):
    # points inside, outside, on vertices, on the box's sides (where '<=' and the even-odd rule
    # decide), ties in u; polygons of 1 to 80 vertices; each point's count as polygon_contains',
    # whether the points come sorted by u (with their u) or not
    rng = np.random.default_rng(seed)
    polys = [_star(rng, int(rng.integers(1, 81)), rng.uniform(30, 70, 2), 20.0) for _ in range(n_polys)]
    pts = np.round(rng.uniform(5, 95, (n_points, 2)) * 4) / 4
    for k, p in enumerate(polys[: n_points // 5]):  # vertices, the extreme ones on the box's sides
        lo_u, lo_v = p[np.argmin(p[:, 0])], p[np.argmin(p[:, 1])]
        pts[5 * k : 5 * k + 5] = [p[0], lo_u, lo_v, p.min(axis=0), [p[:, 0].max(), pts[5 * k + 4, 1]]]
    skips = rng.integers(-1, max(n_points, 1), n_polys) if n_points else np.full(n_polys, -1)
    want = [_enclosed_by_definition(p, pts, int(s)) for p, s in zip(polys, skips)]
    assert count_enclosed(polys, pts, skips).tolist() == want
    order = np.argsort(pts[:, 0], kind="stable")
    rank = np.argsort(order)
    srt = pts[order]
    sorted_skips = [int(rank[s]) if s >= 0 else -1 for s in skips]
    assert count_enclosed(polys, srt, sorted_skips, np.ascontiguousarray(srt[:, 0])).tolist() == want


def test_a_ring_counts_the_points_between_its_sides_and_none_in_its_hole():
    # a square ring as one self-touching polygon (outer square, then the inner one backwards):
    # the even-odd rule puts the hole outside; the own BP (skip) is not counted
    outer = [[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]]
    inner = [[3, 3], [3, 7], [7, 7], [7, 3], [3, 3]]
    ring = np.array(outer + inner, dtype=float)
    pts = np.array([[1.5, 5.0], [5.0, 5.0], [8.5, 1.5], [20.0, 5.0], [5.0, 1.0]])
    assert count_enclosed([ring], pts, [-1]).tolist() == [3]
    assert count_enclosed([ring, ring], pts, [0, 1]).tolist() == [2, 3]
    assert count_enclosed([], pts, []).tolist() == []
    assert count_enclosed([ring], np.empty((0, 2)), [-1]).tolist() == [0]
