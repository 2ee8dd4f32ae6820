"""``detect._candidates_compiled`` in ``detect_specularities``' order (``by_peak``) gives the
candidates of its own order sorted as ``detect_specularities`` sorted them: a stable
``list.sort(key=lambda c: -c.peak)``, ties (equal peaks: quantised intensities, flat boxes) in
the order of the largest component first.

The random frames and masks of ``tests/test_detect_kernels.py`` reach every status code, the
candidates the kernel leaves to numpy (whose peaks join the sort) and the ellipticities numpy
decides; the bench frames and real images there compare ``detect_specularities`` with the numpy
path as a whole.
"""

from __future__ import annotations

from unittest import mock

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from test_detect_kernels import _random_examination, _same_candidates

from simtest.reconstruct import _detect_kernels as _dk
from simtest.reconstruct import detect


def _by_peak_and_sorted(frame, mask, scope):
    with mock.patch.object(detect._DetectFrame, "scope", lambda self: scope):
        got = detect._candidates_compiled(frame, mask, True)
        want = detect._candidates_compiled(frame, mask)
    if got is None:
        return None, want
    want[0].sort(key=lambda c: -c.peak)
    return got, want


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=300, deadline=None)
def test_by_peak_is_the_stable_sort_of_the_candidates(seed):
    got, want = _by_peak_and_sorted(*_random_examination(np.random.default_rng(seed)))
    if got is None:  # full_scale boundaries that overlap: the numpy path, by design
        assert want is None
        return
    assert got[1] == want[1] and _same_candidates(got[0], want[0])


def test_the_random_masks_have_ties_and_declined_candidates_to_sort():
    # the property above means something only if the order it checks is not the area order, has
    # equal peaks to keep in that order, and candidates examined by numpy among them
    rng = np.random.default_rng(1)
    reordered = tied = 0
    spy_codes: list[int] = []
    examine = _dk.examine_candidates

    def spy(*args):
        ints, floats = examine(*args)
        spy_codes.extend(ints[:, _dk.STATUS].tolist())
        return ints, floats

    with mock.patch.object(_dk, "examine_candidates", spy):
        for _ in range(300):
            got, want = _by_peak_and_sorted(*_random_examination(rng))
            if got is None or len(got[0]) < 2:
                continue
            peaks = [c.peak for c in got[0]]
            tied += len(set(peaks)) < len(peaks)
            areas = [c.area_px for c in got[0]]
            reordered += areas != sorted(areas, reverse=True)
    declined = spy_codes.count(_dk.FALLBACK)
    assert reordered > 20 and tied > 20 and declined > 0
