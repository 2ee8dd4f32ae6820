"""simtest asks OpenBLAS for one set of kernels on every x86-64 CPU that runs them (simtest._blas)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from simtest._blas import _cpu_flags, pin_openblas_kernels
from simtest.constants import OPENBLAS_CORE, OPENBLAS_CORE_NEEDS
from simtest.harness.report.provenance import _blas_kernels as blas_kernels

_CAN_PIN = OPENBLAS_CORE_NEEDS <= _cpu_flags()


def _kernels_in_a_fresh_process(env: dict) -> list[str]:
    code = ("import simtest, numpy, scipy.linalg, json; from simtest.harness.report.provenance import _blas_kernels as blas_kernels; "
            "print(json.dumps(blas_kernels()))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not _CAN_PIN, reason="the CPU lacks the instructions of the pinned kernels")
def test_numpy_and_scipy_run_the_pinned_kernels_after_import_simtest():
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    kernels = _kernels_in_a_fresh_process(env)
    assert kernels and all(k.endswith(f" {OPENBLAS_CORE}") for k in kernels), kernels


@pytest.mark.skipif(not _CAN_PIN, reason="the CPU lacks the instructions of the pinned kernels")
def test_a_core_type_the_user_chose_is_kept():
    # Sandybridge's kernels need AVX only: any CPU that runs the pinned ones runs them
    kernels = _kernels_in_a_fresh_process(os.environ | {"OPENBLAS_CORETYPE": "Sandybridge"})
    assert kernels and all(k.endswith(" Sandybridge") for k in kernels), kernels


def test_pinning_leaves_a_set_core_type_alone(monkeypatch):
    monkeypatch.setenv("OPENBLAS_CORETYPE", "Zen")
    assert pin_openblas_kernels() == "Zen"


def test_this_process_runs_the_kernels_it_asked_for():
    # the test session imports simtest before numpy (conftest), as the command line does
    kernels = blas_kernels()
    assert kernels and all(k.startswith("openblas ") for k in kernels)
    asked = os.environ.get("OPENBLAS_CORETYPE")
    if _CAN_PIN:
        assert asked and all(k.endswith(f" {asked}") for k in kernels), (asked, kernels)


@pytest.mark.parametrize("flags, want", [({"avx2", "fma", "avx512f"}, "avx512f"), ({"avx2", "fma"}, "avx2"),
                                         ({"sse4_2"}, "none"), (set(), "none")])
def test_the_vector_extension_is_the_widest_the_cpu_flags_name(monkeypatch, flags, want):
    # a run's provenance records it: renders repeat bit for bit only on the same one
    import simtest._blas as blas
    monkeypatch.setattr(blas, "_cpu_flags", lambda: flags)
    assert blas.vector_extension() == want
