"""``simtest dataset export DIR --format webdataset|hdf5``: a dataset in the formats training code reads.

WebDataset (streamable tar shards)
----------------------------------
``OUT/shard-XXXXX.tar``, one per dataset shard, in the WebDataset layout: the files of a sample
share the key ``<index:08d>`` and follow each other in the tar, one file per field::

    00000003.sensor.png        the 8-bit sensor image (PNG, as stored)
    00000003.normals.npy       float32 (H, W, 3), OpenCV camera frame, 0 outside the mask
    00000003.depth.npy         float32 (H, W), mm
    00000003.linear.npy        float32 (H, W)          00000003.specular.npy  float32 (H, W)
    00000003.mask.npy          bool (H, W)             00000003.highlight_mask.npy  bool (H, W)
    00000003.camera.json       the camera file (model, image size, light rig; simtest's format)
    00000003.json              the manifest row (labels, K, pose, highlights, split)

Read it with ``webdataset.WebDataset("OUT/shard-{00000..00003}.tar").decode()`` or with the
standard library alone (``tarfile``; see :data:`READ_WEBDATASET`). Tar members carry a fixed
time, owner and mode, so the same dataset exports to the same bytes.

HDF5 (BlenderProc's layout)
---------------------------
``OUT/<index>.hdf5``, one file per sample, with the datasets ``colors`` (uint8 (H, W) or
(H, W, 3), the sensor image), ``normals``, ``depth``, ``linear``, ``specular``, ``mask``,
``highlight_mask`` (gzip), ``record`` and ``camera`` (JSON text); read with ``h5py`` alone
(:data:`READ_HDF5`).

Both exports hold ``export.json`` (config fingerprint, format, count) and are written to a
temporary folder swapped into place (:func:`~simtest._io.replace_output_folder`). HDF5 files are
built in memory and written with plain file I/O, so a full disk is an ordinary ``OSError``; any
write failure removes the temporary folder, keeps an earlier export and raises
:class:`~simtest.dataset.shards.DatasetWriteError`.
"""

from __future__ import annotations

import errno
import io
import json
import tarfile
from pathlib import Path

import h5py
import numpy as np

from simtest._io import atomic_write_json, replace_output_folder
from simtest.dataset.reader import SimtestDataset
from simtest.dataset.shards import WRITE_ERRNOS, DatasetError, DatasetWriteError, decode_png

__all__ = ["FORMATS", "READ_HDF5", "READ_WEBDATASET", "export"]

#: The export formats' names (``--format``).
FORMATS = ("webdataset", "hdf5")

_FIELDS = ("normals", "depth", "linear", "specular", "mask", "highlight_mask")

#: Reading a WebDataset export with the standard library and numpy alone.
READ_WEBDATASET = """\
import io, json, tarfile, numpy as np
from PIL import Image
samples = {}
with tarfile.open("OUT/shard-00000.tar") as tar:
    for m in tar:
        key, field = m.name.split(".", 1)
        data = tar.extractfile(m).read()
        s = samples.setdefault(key, {})
        if field.endswith("json"):                 # json (the row), camera.json
            s["record" if field == "json" else "camera"] = json.loads(data)
        elif field.endswith(".npy"):
            s[field[:-4]] = np.load(io.BytesIO(data))
        else:  # sensor.png
            s["sensor"] = np.asarray(Image.open(io.BytesIO(data)))"""

#: Reading an HDF5 export with h5py alone.
READ_HDF5 = """\
import json, h5py
with h5py.File("OUT/3.hdf5", "r") as f:
    image = f["colors"][()]                 # (H, W) or (H, W, 3) uint8
    normals = f["normals"][()]              # (H, W, 3) float32, camera frame
    record = json.loads(f["record"][()])    # labels: K, pose, highlights, split"""


def _add(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode = len(data), 0, 0o644
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    tar.addfile(info, io.BytesIO(data))


def _webdataset(ds: SimtestDataset, tmp: Path) -> int:
    by_shard: dict[int, list[int]] = {}
    for k, row in enumerate(ds.rows):
        by_shard.setdefault(int(row["shard"]), []).append(k)
    for shard, positions in sorted(by_shard.items()):
        with tarfile.open(tmp / f"shard-{shard:05d}.tar", "w", format=tarfile.USTAR_FORMAT) as tar:
            for k in positions:
                s = ds[k]
                key = f"{s['index']:08d}"
                _add(tar, f"{key}.sensor.png", np.asarray(s["sensor_png"], np.uint8).tobytes())
                for f in _FIELDS:
                    buf = io.BytesIO()
                    np.lib.format.write_array(buf, np.ascontiguousarray(s[f]), allow_pickle=False)
                    _add(tar, f"{key}.{f}.npy", buf.getvalue())
                if "camera" in s["record"]:
                    _add(tar, f"{key}.camera.json", json.dumps(s["record"]["camera"], indent=2).encode())
                _add(tar, f"{key}.json", json.dumps(s["record"], sort_keys=True).encode())
    return len(by_shard)


def _write_file(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` (plain file I/O: a full disk is an OSError here)."""
    with open(path, "wb") as fh:
        fh.write(data)


def _hdf5(ds: SimtestDataset, tmp: Path) -> int:
    for k in range(len(ds)):
        s = ds[k]
        buf = io.BytesIO()  # built in memory: the HDF5 library never sees a failing disk
        with h5py.File(buf, "w", track_order=True) as f:
            f.create_dataset("colors", data=decode_png(s["sensor_png"]), compression="gzip")
            for name in _FIELDS:
                f.create_dataset(name, data=s[name], compression="gzip")
            f.create_dataset("record", data=json.dumps(s["record"], sort_keys=True))
            if "camera" in s["record"]:
                f.create_dataset("camera", data=json.dumps(s["record"]["camera"], indent=2))
        _write_file(tmp / f"{s['index']}.hdf5", buf.getvalue())
    return len(ds)


def export(root, fmt: str, out=None) -> Path:
    """Export a dataset folder to WebDataset tar shards or BlenderProc-style HDF5 files.

    Parameters
    ----------
    root : path
        A complete dataset folder.
    fmt : str
        ``"webdataset"`` or ``"hdf5"`` (see the module notes for the layouts).
    out : path, optional
        Output folder (default: ``<root>-<fmt>`` beside the dataset). An existing export there is
        replaced as a whole; any other non-empty folder is refused.

    Returns
    -------
    Path
        The output folder.

    Raises
    ------
    DatasetError
        Unknown format, incomplete dataset, manifest paths outside the folder.
    DatasetWriteError
        Something else in the way of ``out``, or the export cannot be written; an earlier
        export at ``out`` is left as it was.
    """
    if fmt not in FORMATS:
        raise DatasetError(f"--format {fmt!r}: not one of {', '.join(FORMATS)}")
    root = Path(root)
    out = Path(out) if out is not None else root.with_name(f"{root.name}-{fmt}")
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (out / "export.json").is_file())):
        raise DatasetWriteError(f"{out}: exists and is not a simtest export: refusing to replace it")
    ds = SimtestDataset(root, keys=("sensor_png", *_FIELDS), with_record=True)
    tmp = None

    def fill(folder: Path) -> None:
        nonlocal tmp
        tmp = folder
        files = _webdataset(ds, folder) if fmt == "webdataset" else _hdf5(ds, folder)
        atomic_write_json(folder / "export.json", {
            "format": fmt, "source": str(root), "samples": len(ds), "files": files,
            "config_fingerprint": ds.card.get("config_fingerprint"),
            "reading": READ_WEBDATASET if fmt == "webdataset" else READ_HDF5,
        })

    try:
        replace_output_folder(out, fill)
    except OSError as exc:
        if exc.errno in WRITE_ERRNOS or tmp is None or str(exc.filename or "").startswith(str(tmp)):
            raise _write_error(exc, out) from None
        raise DatasetError(f"{exc.filename or root}: cannot read: {exc.strerror or exc}") from None
    finally:
        ds.close()
    return out


def _write_error(exc: OSError, out: Path) -> DatasetWriteError:
    """One line for an export that could not be written."""
    why = {errno.ENOSPC: "no space left on device", errno.EDQUOT: "disk quota exceeded",
           errno.EROFS: "read-only file system", errno.EACCES: "permission denied",
           errno.EPERM: "permission denied"}.get(exc.errno, exc.strerror or str(exc))
    return DatasetWriteError(f"{out}: cannot write the export: {why}; nothing was left behind and "
                             "an earlier export there is unchanged")

