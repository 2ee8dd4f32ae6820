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


def pytest_collection_modifyitems(config, items):
    """Modules holding a test marked ``slow`` run first, each module's tests kept together.

    Under ``--dist worksteal`` (pyproject's addopts) each worker starts on a contiguous half of
    this order and takes tests from the other when it runs out: a long test left for the end
    would keep one core busy while the other idles, whereas cheap tests at the end even out.
    """
    slow = {item.module.__name__ for item in items
            if item.get_closest_marker("slow") is not None and getattr(item, "module", None) is not None}
    if slow:
        items.sort(key=lambda item: getattr(getattr(item, "module", None), "__name__", None) not in slow)
