"""Datasets for learning: rendered samples with exact labels, in shards readable without simtest.

``simtest dataset generate CONFIG --out DIR`` renders the samples a TOML config describes
(:mod:`simtest.dataset.config`), each a pure function of (root seed, index)
(:mod:`simtest.dataset.sample`), into shards with a manifest and a card
(:mod:`simtest.dataset.shards`), locally or on a Dask cluster (:mod:`simtest.dataset.generate`);
``simtest dataset verify DIR`` checks it (:mod:`simtest.dataset.verify`),
``simtest dataset show DIR`` draws a contact sheet (:mod:`simtest.dataset.show`),
``simtest dataset export DIR --format webdataset|hdf5`` converts it (:mod:`simtest.dataset.export`)
and ``simtest.dataset.open(DIR)`` reads it lazily, ``.torch(...)`` for a PyTorch ``DataLoader``
(:mod:`simtest.dataset.reader`).

Functions: ``simtest.dataset.generate.generate``, ``simtest.dataset.verify.verify``,
``simtest.dataset.open``, ``simtest.dataset.collate``. Attributes are imported on first use so that ``import simtest.dataset`` stays cheap; ``dir()``
lists them.
"""

from __future__ import annotations

import importlib

__all__ = ["collate", "load_config", "open", "render_sample"]

_WHERE = {
    "open": ("simtest.dataset.reader", "open_dataset"),
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
