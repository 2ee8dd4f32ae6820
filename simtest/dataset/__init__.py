"""Datasets for learning: rendered samples with exact labels, in shards readable without simtest.

``simtest dataset generate CONFIG --out DIR`` renders the samples a TOML config describes
(:mod:`simtest.dataset.config`), each a pure function of (root seed, index)
(:mod:`simtest.dataset.sample`), into shards with a manifest and a card
(:mod:`simtest.dataset.shards`), locally or on a Dask cluster (:mod:`simtest.dataset.generate`);
``simtest dataset verify DIR`` checks it (:mod:`simtest.dataset.verify`) and
``simtest.dataset.open(DIR)`` reads it lazily (:mod:`simtest.dataset.reader`).

Functions: ``simtest.dataset.generate.generate``, ``simtest.dataset.verify.verify``,
``simtest.dataset.open``. Attributes are imported lazily so that ``import simtest.dataset`` stays cheap.
"""

from __future__ import annotations

__all__ = ["load_config", "open", "render_sample"]


def __getattr__(name: str):
    if name == "open":
        from simtest.dataset.reader import open_dataset

        return open_dataset
    if name == "load_config":
        from simtest.dataset.config import load_config

        return load_config
    if name == "render_sample":
        from simtest.dataset.sample import render_sample

        return render_sample
    raise AttributeError(f"module 'simtest.dataset' has no attribute {name!r}")
