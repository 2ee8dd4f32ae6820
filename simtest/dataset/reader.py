"""Read a dataset lazily: ``simtest.dataset.open(DIR)``.

The returned :class:`SimtestDataset` is a map-style sequence: ``len(ds)``, ``ds[i]`` (a dict of
numpy arrays plus the manifest row under ``"record"``) and iteration. Shard files are opened on
first use and kept open (a few per process), so reading is lazy and cheap. When PyTorch is
installed the class is also a ``torch.utils.data.Dataset`` (hand it to a ``DataLoader``; with
``keys=[...]`` and ``with_record=False`` the default collate stacks the arrays).

Without simtest (numpy and PIL alone)
-------------------------------------
.. code-block:: python

    import io, json, numpy as np
    from PIL import Image
    rows = [json.loads(line) for line in open("DIR/manifest.jsonl")]
    row = rows[0]
    z = np.load("DIR/" + row["npz"])                  # DIR/shards/shard-00000.npz
    key = f"{row['index']:08d}/"
    image = np.asarray(Image.open(io.BytesIO(z[key + "sensor_png"].tobytes())))  # (H, W) uint8
    normals = z[key + "normals"]                       # (H, W, 3) float32, camera frame
    bp_px = row["highlights"][0]["bp_px"]              # [u, v]
"""

from __future__ import annotations

import importlib.util
from collections import OrderedDict
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from simtest.dataset.shards import decode_png, entry_name, read_card, read_manifest

__all__ = ["SimtestDataset", "open_dataset", "torch_available"]


def torch_available() -> bool:
    """True when PyTorch can be imported (checked with ``importlib.util.find_spec``, no import).

    Returns
    -------
    bool
        Whether :class:`SimtestDataset` is also a ``torch.utils.data.Dataset``.
    """
    return importlib.util.find_spec("torch") is not None


def _base() -> type:
    if torch_available():
        import torch.utils.data

        return torch.utils.data.Dataset
    return object


_ARRAYS = ("sensor", "linear", "specular", "normals", "depth", "mask", "highlight_mask")


class SimtestDataset(_base()):  # type: ignore[misc]
    """A dataset folder as a lazy sequence of samples.

    Parameters
    ----------
    root : path
        Dataset folder (written by ``simtest dataset generate``).
    keys : sequence of str, optional
        Arrays to load per sample (default: all). ``"sensor"`` is the decoded 8-bit image;
        ``"sensor_png"`` the raw PNG bytes.
    with_record : bool
        Include the manifest row (labels, parameters, K, pose, highlights) under ``"record"``.
    max_open : int
        Shard files kept open at once.

    Raises
    ------
    DatasetError
        If ``root`` is not a complete dataset.
    KeyError
        If ``keys`` names an unknown array.

    Notes
    -----
    ``ds[i]`` returns ``{"index": i, <key>: ndarray, ..., "record": dict}``. Shapes for an image
    of H x W pixels (rows = v, columns = u): ``sensor`` uint8 (H, W); ``linear``, ``specular`` and
    ``depth`` (mm) float32 (H, W); ``normals`` float32 (H, W, 3), unit vectors in the OpenCV
    camera frame facing the camera, zero outside ``mask``; ``mask`` and ``highlight_mask`` bool
    (H, W). Negative indices count from the end; an out-of-range index raises IndexError and a
    non-integer one TypeError.
    """

    def __init__(self, root, keys: Sequence[str] | None = None, with_record: bool = True,
                 max_open: int = 4):
        self.root = Path(root)
        self.card = read_card(self.root)
        self.rows = read_manifest(self.root)
        allowed = (*_ARRAYS, "sensor_png")
        keys = tuple(keys) if keys is not None else _ARRAYS
        bad = [k for k in keys if k not in allowed]
        if bad:
            raise KeyError(f"unknown array(s) {bad}; known: {', '.join(allowed)}")
        self.keys = keys
        self.with_record = with_record
        self.max_open = max_open
        self._open: OrderedDict = OrderedDict()

    def __len__(self) -> int:
        return len(self.rows)

    def _shard(self, rel: str):
        z = self._open.get(rel)
        if z is None:
            z = np.load(self.root / rel, allow_pickle=False)
            self._open[rel] = z
            while len(self._open) > self.max_open:
                _, old = self._open.popitem(last=False)
                old.close()
        else:
            self._open.move_to_end(rel)
        return z

    def __getitem__(self, i: int) -> dict:
        if not isinstance(i, int | np.integer):
            raise TypeError(f"index must be an integer, got {type(i).__name__}")
        n = len(self.rows)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"sample {i} out of range 0..{n - 1}")
        row = self.rows[i]
        z = self._shard(row["npz"])
        out: dict = {"index": int(row["index"])}
        for k in self.keys:
            if k == "sensor":
                out[k] = decode_png(z[entry_name(row["index"], "sensor_png")])
            else:
                out[k] = z[entry_name(row["index"], k)]
        if self.with_record:
            out["record"] = row
        return out

    def __iter__(self) -> Iterator[dict]:
        for i in range(len(self)):
            yield self[i]

    def close(self) -> None:
        """Close the open shard files."""
        while self._open:
            _, z = self._open.popitem()
            z.close()

    def __getstate__(self):  # DataLoader workers get a copy without open files
        d = dict(self.__dict__)
        d["_open"] = OrderedDict()
        return d


def open_dataset(root, keys: Sequence[str] | None = None, with_record: bool = True) -> SimtestDataset:
    """Open a dataset folder lazily (``simtest.dataset.open``).

    Parameters
    ----------
    root : path
        Dataset folder (written by ``simtest dataset generate``).
    keys : sequence of str, optional
        Arrays to load per sample (default: all); see :class:`SimtestDataset`.
    with_record : bool
        Include the manifest row under ``"record"``.

    Returns
    -------
    SimtestDataset

    Raises
    ------
    DatasetError
        If ``root`` is not a complete dataset (card or manifest missing or unreadable).
    KeyError
        If ``keys`` names an unknown array.
    """
    return SimtestDataset(root, keys=keys, with_record=with_record)
