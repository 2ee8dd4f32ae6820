"""Shared test fixtures."""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")

# Point Dr.Jit at a suitable LLVM before any test imports Mitsuba.
from simtest._llvm import configure_llvm_env  # noqa: E402

configure_llvm_env()
os.environ.setdefault("SIMTEST_TEST", "1")
