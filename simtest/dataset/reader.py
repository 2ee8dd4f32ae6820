"""Read a dataset lazily (``simtest.dataset.open(DIR)``) and feed it to PyTorch.

:class:`SimtestDataset` is a map-style sequence (``len(ds)``, ``ds[i]``, iteration); shard files
are opened on first use and a few kept open. ``ds.torch(keys=..., transform=...)`` gives a view for
``torch.utils.data.DataLoader`` whose items are dicts of tensors; manifest rows, which differ between
families, stay out of the batch (``view.record(index)``, or ``with_record=True`` with
``collate_fn=simtest.dataset.collate``)::

    view = simtest.dataset.open("DIR", split="train").torch(keys=("sensor", "normals", "mask"))
    loader = torch.utils.data.DataLoader(view, batch_size=8, shuffle=True, num_workers=2)
    batch = next(iter(loader))   # batch["sensor"]: (8, 1, H, W) float32 in [0, 1]
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np

from simtest._lazy import require
from simtest.dataset.shards import (MANIFEST_NAME, DatasetError, decode_png, entry_name, labels_sha256,
                                    read_card, read_manifest, shard_path_from_row)

__all__ = ["SPLITS", "SimtestDataset", "TorchView", "collate"]

#: Split names a sample may carry (``row["split"]``).
SPLITS = ("train", "val", "test")

_ARRAYS = ("sensor", "linear", "specular", "normals", "depth", "mask", "highlight_mask")

#: Per-sample fixed-shape labels a torch view can return beside the arrays (from the manifest row).
_ROW_TENSORS = ("K", "cam_to_world")


class SimtestDataset:
    """A dataset folder as a lazy sequence of samples (``simtest.dataset.open``).

    Parameters
    ----------
    root : path
        Dataset folder (written by ``simtest dataset generate``).
    keys : sequence of str, optional
        Arrays to load per sample (default: all). ``"sensor"`` is the decoded 8-bit image;
        ``"sensor_png"`` the raw PNG bytes.
    with_record : bool
        Include the manifest row (labels, parameters, K, pose, highlights) under ``"record"``.
    split : str, optional
        Keep only one split (``"train"``, ``"val"`` or ``"test"``); positions then run over that
        split, ``ds[k]["index"]`` is the sample's index in the dataset.
    max_open : int
        Shard files kept open at once.

    Raises
    ------
    DatasetError
        If ``root`` is not a complete dataset or a manifest row names a shard file outside
        ``root/shards``; from ``ds[i]`` when the row no longer matches its ``labels_sha256``.
    KeyError
        If ``keys`` names an unknown array, or ``split`` an unknown split.

    Notes
    -----
    ``ds[i]`` returns ``{"index": i, <key>: ndarray, ..., "record": dict}``, for H x W pixels (rows =
    v): ``sensor`` uint8 (H, W); ``linear``, ``specular``, ``depth`` (mm) float32 (H, W); ``normals``
    float32 (H, W, 3), unit, OpenCV camera frame, zero outside ``mask``; ``mask`` and
    ``highlight_mask`` bool (H, W). Negative indices count from the end.
    """

    def __init__(self, root, keys: Sequence[str] | None = None, with_record: bool = True,
                 split: str | None = None, max_open: int = 4):
        self.root = Path(root)
        self.card = read_card(self.root)
        rows = read_manifest(self.root)
        #: True when any sample of the whole dataset (every split) has an RGB sensor image.
        self.has_rgb = any(r.get("color") == "rgb" for r in rows)
        allowed = (*_ARRAYS, "sensor_png")
        keys = tuple(keys) if keys is not None else _ARRAYS
        bad = [k for k in keys if k not in allowed]
        if bad:
            raise KeyError(f"unknown array(s) {bad}; known: {', '.join(allowed)}")
        if split is not None and split not in SPLITS:
            raise KeyError(f"unknown split {split!r}; known: {', '.join(SPLITS)}")
        self._paths = [shard_path_from_row(self.root, r) for r in rows]  # refuses ../ and /abs
        if split is not None:
            keep = [k for k, r in enumerate(rows) if r.get("split") == split]
            rows, self._paths = [rows[k] for k in keep], [self._paths[k] for k in keep]
        self.rows, self.split, self.keys = rows, split, keys
        self.with_record, self.max_open = with_record, max_open
        self._open: OrderedDict = OrderedDict()
        self._checked: set[int] = set()

    def __len__(self) -> int:
        return len(self.rows)

    def _shard(self, i: int):
        rel = self.rows[i]["npz"]  # checked at open: shards/shard-XXXXX.npz
        z = self._open.get(rel)
        if z is None:
            z = np.load(self._paths[i], allow_pickle=False)
            self._open[rel] = z
            while len(self._open) > self.max_open:
                _, old = self._open.popitem(last=False)
                old.close()
        else:
            self._open.move_to_end(rel)
        return z

    def _position(self, i) -> int:
        if not isinstance(i, int | np.integer):
            raise TypeError(f"index must be an integer, got {type(i).__name__}")
        n = len(self.rows)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"sample {i} out of range 0..{n - 1}")
        return int(i)

    def _row(self, i: int) -> dict:
        """Row ``i``, once its labels are checked against their hash (edited labels are refused)."""
        row = self.rows[i]
        if i not in self._checked:
            if row.get("labels_sha256") != labels_sha256(row):
                raise DatasetError(f"{self.root / MANIFEST_NAME}: shard {row.get('shard')}, sample {row.get('index')}: "
                                   "labels differ from their labels_sha256 (edited or damaged): refused; run "
                                   f"`simtest dataset verify {self.root}`")
            self._checked.add(i)
        return row

    def __getitem__(self, i: int) -> dict:
        i = self._position(i)
        row = self._row(i)
        z = self._shard(i)
        out: dict = {"index": int(row["index"])}
        for k in self.keys:
            a = z[entry_name(row["index"], "sensor_png" if k == "sensor" else k)]
            out[k] = decode_png(a) if k == "sensor" else a
        if self.with_record:
            out["record"] = row
        return out

    def __iter__(self) -> Iterator[dict]:
        return (self[i] for i in range(len(self)))

    def close(self) -> None:
        """Close the open shard files."""
        while self._open:
            _, z = self._open.popitem()
            z.close()

    def __getstate__(self):  # DataLoader workers get a copy without open files
        d = dict(self.__dict__)
        d["_open"] = OrderedDict()
        return d

    def torch(self, keys: Sequence[str] = ("sensor", "normals", "mask"),
              transform: Callable[[dict], dict] | None = None, with_record: bool = False) -> "TorchView":
        """A view of this dataset for ``torch.utils.data.DataLoader`` (needs PyTorch).

        Parameters
        ----------
        keys : sequence of str
            Arrays (as in :class:`SimtestDataset`) and row labels ``"K"`` (3, 3) and
            ``"cam_to_world"`` (4, 4) to return as tensors.
        transform : callable, optional
            ``transform(item) -> item`` applied to each item's dict of tensors (augmentation,
            resizing); must be picklable (a module-level function) for ``num_workers > 0``.
        with_record : bool
            Also return the manifest row under ``"record"``; batch such items with
            ``collate_fn=simtest.dataset.collate`` (rows differ between families, so the default
            collate cannot stack them).

        Returns
        -------
        TorchView

        Raises
        ------
        KeyError
            If ``keys`` names an unknown array or label.
        simtest._lazy.MissingBackend
            If PyTorch is not installed (one line: ``pip install "simtest[torch]"``).
        """
        return TorchView(self, keys=keys, transform=transform, with_record=with_record)


def _to_tensor(torch, key: str, a, sensor_channels: int = 1):
    """numpy -> tensor: images channel-first, the sensor as float in [0, 1] with ``sensor_channels`` channels."""
    a = np.asarray(a)
    if key == "sensor":  # (H, W) or (H, W, 3) uint8 -> (C, H, W) float32 in [0, 1]
        a = np.repeat(a[None], sensor_channels, axis=0) if a.ndim == 2 else np.moveaxis(a, -1, 0)
        return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32) / np.float32(255.0))
    if key == "normals":  # (H, W, 3) -> (3, H, W)
        return torch.from_numpy(np.ascontiguousarray(np.moveaxis(a, -1, 0)))
    if a.dtype == np.float64:
        a = a.astype(np.float32)
    return torch.from_numpy(np.ascontiguousarray(a))


class TorchView:
    """Items of a :class:`SimtestDataset` as dicts of PyTorch tensors (map-style dataset).

    Parameters
    ----------
    dataset : SimtestDataset
        The dataset to read (its ``split`` applies).
    keys, transform, with_record
        See :meth:`SimtestDataset.torch`.

    Notes
    -----
    Item layout: ``"index"`` (int, the sample's index in the dataset); ``"sensor"`` float32
    (C, H, W) in [0, 1] (the 8-bit image / 255), C = 1 when every sample of the dataset is grey,
    else 3 (RGB tissue samples; a grey sample's channel repeated); ``"normals"`` float32 (3, H, W)
    in the OpenCV camera frame; ``"linear"``, ``"specular"``, ``"depth"`` (mm) float32 (H, W);
    ``"mask"``, ``"highlight_mask"`` bool (H, W); ``"K"`` float32 (3, 3) in pixels with integer
    pixel centres; ``"cam_to_world"`` float32 (4, 4). Samples of one batch must share a size (the
    default config has a single resolution).
    """

    def __init__(self, dataset: SimtestDataset, keys: Sequence[str] = ("sensor", "normals", "mask"),
                 transform: Callable[[dict], dict] | None = None, with_record: bool = False):
        require("torch", purpose="simtest.dataset.open(DIR).torch()")  # here, not in a worker
        keys = tuple(keys)
        bad = [k for k in keys if k not in (*_ARRAYS, *_ROW_TENSORS)]
        if bad:
            raise KeyError(f"unknown key(s) {bad}; known: {', '.join((*_ARRAYS, *_ROW_TENSORS))}")
        arrays = tuple(k for k in keys if k in _ARRAYS)
        self.dataset = SimtestDataset(dataset.root, keys=arrays, with_record=True, split=dataset.split,
                                      max_open=dataset.max_open)
        self.keys, self.transform, self.with_record = keys, transform, with_record
        #: Channels of the ``"sensor"`` tensor, the same for every split of one dataset.
        self.sensor_channels = 3 if dataset.has_rgb else 1

    def __len__(self) -> int:
        return len(self.dataset)

    def record(self, index: int) -> dict:
        """The manifest row (labels, parameters, highlights) of the sample with dataset ``index``.

        Raises
        ------
        DatasetError
            If the row's labels no longer match their ``labels_sha256``.
        IndexError
            If no sample of this view has that index.
        """
        for k, r in enumerate(self.dataset.rows):
            if r["index"] == index:
                return self.dataset._row(k)
        raise IndexError(f"no sample {index} in this view")

    def __getitem__(self, i: int) -> dict:
        torch = require("torch")
        item = self.dataset[i]
        row = item["record"]
        out: dict = {"index": item["index"]}
        for k in self.keys:
            out[k] = _to_tensor(torch, k, row[k] if k in _ROW_TENSORS else item[k], self.sensor_channels)
        if self.transform is not None:
            out = self.transform(out)
        if self.with_record:
            out["record"] = row
        return out


def collate(batch: list[dict]) -> dict:
    """Batch items of a :class:`TorchView` made with ``with_record=True``.

    Parameters
    ----------
    batch : list of dict
        Items; tensors of one key must share a shape.

    Returns
    -------
    dict
        ``torch.utils.data.default_collate`` of everything but ``"record"``, and ``"record"`` as a
        list of the rows (their keys differ between families).
    """
    default_collate = require("torch.utils.data", purpose="simtest.dataset.collate").default_collate
    rest = [{k: v for k, v in b.items() if k != "record"} for b in batch]
    out = default_collate(rest)
    if batch and "record" in batch[0]:
        out["record"] = [b["record"] for b in batch]
    return out
