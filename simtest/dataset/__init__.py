"""Datasets for learning: rendered samples with exact labels, in shards readable without simtest.

``simtest dataset generate CONFIG --out DIR`` renders the samples of a TOML config
(:mod:`~simtest.dataset.config`, :mod:`~simtest.dataset.sample`) into shards with a manifest and a
card (:mod:`~simtest.dataset.shards`, :mod:`~simtest.dataset.generate`); ``verify``, ``show`` and
``export`` check, draw and convert it; ``simtest.dataset.open(DIR)`` reads it lazily
(:mod:`~simtest.dataset.reader`). Attributes are imported on first use, so ``import
simtest.dataset`` stays cheap.
"""

from __future__ import annotations

import importlib

__all__ = ["collate", "load_config", "open", "render_sample"]

_WHERE = {
    "open": ("simtest.dataset.reader", "SimtestDataset"),
    "collate": ("simtest.dataset.reader", "collate"),
    "load_config": ("simtest.dataset.config", "load_config"),
    "render_sample": ("simtest.dataset.sample", "render_sample"),
}


def __getattr__(name: str):
    if name in _WHERE:
        module, attr = _WHERE[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'simtest.dataset' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
