"""Arrays handed to Dr.Jit start on a 64-byte boundary, so that a render compiles one variant of each kernel.

Dr.Jit's LLVM backend reads a NumPy array in place and compiles its kernels for whether each input is 64-byte
aligned (``align 64``) or not (``align 1``); a heap allocation lands on either at random, so the same scene
rendered twice could compile a kernel twice (the colonoscope's largest, 337 kB of IR, about 0.2 s each time).
:func:`simtest.render.wavefront.dr_input` aligns what the renderer hands over.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest.render.wavefront import DR_ALIGN_BYTES, dr_columns, dr_input


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2000), st.integers(0, 15), st.sampled_from([np.float32, np.float64, np.uint32, np.int64]),
       st.sampled_from([np.float32, np.uint32]), st.booleans())
def test_dr_input_is_the_array_cast_contiguous_and_aligned(n, shift, src_dtype, dtype, strided):
    # exact: the values cast to the asked type, the shape kept, C order, the data on a 64-byte boundary
    # (an empty array reads none), from any start address (shift: elements off an aligned buffer) and
    # strided views alike
    buf = np.arange(2 * n + 64, dtype=src_dtype)
    a = buf[shift:shift + 2 * n:2] if strided else buf[shift:shift + n]
    out = dr_input(a, dtype)
    assert out.dtype == dtype and out.shape == a.shape and out.flags.c_contiguous
    assert out.size == 0 or out.ctypes.data % DR_ALIGN_BYTES == 0
    np.testing.assert_array_equal(out, a.astype(dtype))
    assert dr_input(out, dtype) is out  # already aligned: handed over as it is


def test_dr_columns_are_the_columns():
    d = np.arange(30, dtype=np.float64).reshape(10, 3)[1:]
    cols = dr_columns(d)
    assert len(cols) == 3
    for k, c in enumerate(cols):
        assert c.ctypes.data % DR_ALIGN_BYTES == 0
        np.testing.assert_array_equal(c, d[:, k].astype(np.float32))


@pytest.mark.render
@pytest.mark.parametrize("scene", ["colonoscope", "laparoscope_liver"])
def test_every_kernel_of_an_endoscope_render_reads_aligned_inputs(scene):
    # each kernel's inputs (its parameter block's pointers) are loaded with the alignment Dr.Jit compiled
    # it for: none is 'align 1', the variant an unaligned NumPy array makes (before dr_input: 142 such
    # loads in the colonoscope's kernels, 617 in the liver's, at a tenth of their films)
    import drjit as dr

    from simtest.render.render import render_scene
    from simtest.scene.spec import load_scene, with_overrides

    spec = load_scene(scene)
    spec = with_overrides(spec, {"camera.width_px": round(spec.camera.width_px / 10),
                                 "camera.height_px": round(spec.camera.height_px / 10), "render.spp": 1})
    dr.kernel_history()  # (clears it)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        render_scene(spec, seed=3)
        kernels = [k for k in dr.kernel_history() if "ir" in k]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert len(kernels) > 50  # the renderer's wavefront kernels were seen
    unaligned = [k["hash"] for k in kernels
                 if re.search(r"= load <\d+ x \w+>, ptr %\w+_p3, align 1,", k["ir"].getvalue())]
    assert not unaligned, f"{len(unaligned)} of {len(kernels)} kernels read an unaligned input"
