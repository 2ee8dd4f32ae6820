"""Constants shared by rooms live in simtest.constants, written once."""

from __future__ import annotations

import ast
from pathlib import Path

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from simtest import constants
from simtest.reconstruct.detect import luma

PACKAGE = Path(__file__).resolve().parents[1] / "simtest"


def _code_numbers():
    """(file, value) of every number literal in the code (docstrings and comments are not code)."""
    for p in sorted(PACKAGE.rglob("*.py")):
        if p.name == "constants.py":
            continue
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow) \
                    and isinstance(node.left, ast.Constant) and isinstance(node.right, ast.Constant):
                yield p.name, node.left.value ** node.right.value
            elif isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
                    and not isinstance(node.value, bool):
                yield p.name, node.value


def test_the_seed_bound_is_written_once():
    assert constants.MAX_SEED == 2**31 - 1
    assert [f for f, v in _code_numbers() if v in (2**31, 2**31 - 1)] == []


def test_the_grey_weights_are_written_once_and_sum_to_one():
    weights = set(constants.LUMA_BT601) | set(constants.LUMINANCE_BT709)
    for w in (constants.LUMA_BT601, constants.LUMINANCE_BT709):
        assert abs(sum(w) - 1.0) < 1e-12
    assert [(f, v) for f, v in _code_numbers() if v in weights] == []


def test_detection_luma_is_opencvs_grey():
    rgb = np.random.default_rng(3).integers(0, 256, (40, 50, 3), dtype=np.uint8)
    ours = luma(rgb)
    theirs = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float64)
    # OpenCV rounds to the nearest integer (0.5) with 14-bit fixed-point weights (3 x 255 / 2^14)
    assert np.max(np.abs(ours - theirs)) <= 0.5 + 3 * 255 / 2**14


def test_thread_environment_is_written_once():
    assert all(v == "1" for v in constants.SINGLE_THREAD_ENV.values())
    hits = [p.name for p in PACKAGE.rglob("*.py") if p.name != "constants.py"
            and '"OPENBLAS_NUM_THREADS"' in p.read_text(encoding="utf-8")]
    assert hits == []


@settings(max_examples=60, deadline=None)
@given(st.floats(0.2, 6.0), st.sampled_from([np.float32, np.float64]))
def test_the_gaussian_radius_is_that_of_opencvs_kernel(sigma, dtype):
    # the impulse response of cv2.GaussianBlur is its kernel: nonzero exactly on 2 R + 1 pixels
    # (float kernels of these sigmas have no tap that underflows to zero)
    n = 2 * 40 + 1
    delta = np.zeros((n, n), dtype)
    delta[40, 40] = 1
    out = cv2.GaussianBlur(delta, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    cols = np.flatnonzero(out[40])
    r = constants.gaussian_radius_px(sigma)
    assert cols.tolist() == list(range(40 - r, 40 + r + 1)), (sigma, cols.tolist())
