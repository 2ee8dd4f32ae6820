"""Shared test fixtures."""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")

# Point Dr.Jit at a suitable LLVM before any test imports Mitsuba.
from simtest._llvm import configure_llvm_env  # noqa: E402

configure_llvm_env()
os.environ.setdefault("SIMTEST_TEST", "1")

# Property tests explore new examples on every local run (that is how they find bugs); under CI
# (CI=true) they draw the same examples every time, so that a landing does not hang on luck.
from hypothesis import settings  # noqa: E402

settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
    settings.load_profile("ci")
