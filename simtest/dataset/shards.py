"""On-disk format of a dataset: shards, manifest and card.

::
    DIR/dataset.json                 the card: config, seed, version, counts, channels and units
    DIR/manifest.jsonl               one JSON row per sample (labels, shard, per-array sha256)
    DIR/shards/shard-00000.npz       the arrays of samples 0 .. shard_size-1 (lossless .npz)
    DIR/shards/shard-00000.json      the rows of those samples + the shard file's sha256

A shard ``.npz`` holds one entry per (sample, array), named ``"<index:08d>/<array>"``; the sensor
image is stored as the bytes of its 8-bit PNG (``"<index>/sensor_png"``, :func:`decode_png`).
Entries carry a fixed zip timestamp, so identical samples give byte-identical shards. A shard is
written to ``.npz.tmp`` and renamed when complete; its ``.json``, written after the rename, marks it
complete. The manifest and the card's final counts are written last.

Each row carries ``labels_sha256`` (:func:`labels_sha256`); a shard's zip comment binds it to its
shard number, config fingerprint and label hashes (:func:`shard_comment`); the card carries
``manifest_sha256`` and ``card_sha256`` (:func:`card_sha256`). Manifest rows name their shard exactly
as ``shards/shard-XXXXX.npz`` (:func:`shard_path_from_row`), so a manifest cannot point outside the
dataset folder.
"""

from __future__ import annotations

import errno
import hashlib
import io
import json
import os
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np
from PIL import Image

from simtest._io import TMP_SUFFIX, atomic_write_json, atomic_write_text

__all__ = ["CARD_NAME", "FORMAT", "FORMAT_VERSION", "MANIFEST_NAME", "DatasetError", "DatasetWriteError", "ShardWriter",
           "array_sha256", "card_sha256", "file_sha256", "json_sha256", "labels_sha256", "read_card", "read_manifest",
           "read_shard_rows", "shard_comment", "shard_json_path", "shard_npz_path", "shard_path_from_row"]

FORMAT = "simtest-dataset"
FORMAT_VERSION = 1
CARD_NAME = "dataset.json"
MANIFEST_NAME = "manifest.jsonl"
SHARDS_DIR = "shards"
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)
#: errno values that mean an output cannot be written (reported as one line).
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EFBIG})

#: Arrays deflated with ``compress=True`` (sparse masks and specular image); the float32 arrays carry
#: Monte Carlo noise in their low bits and are stored; the sensor image is already a PNG.
DEFLATED = frozenset({"mask", "highlight_mask", "specular"})
#: The only form a manifest row's ``npz`` may take (relative, inside the dataset folder).
_NPZ_REL = re.compile(r"shards/shard-([0-9]{5,})\.npz")


class DatasetError(RuntimeError):
    """A dataset folder cannot be written or read; the message names the path."""


class DatasetWriteError(DatasetError):
    """An output cannot be written (disk full, read-only, quota); one line naming it.

    What was there before is left intact and the temporary files are removed.
    """


def array_sha256(a: np.ndarray) -> str:
    """64 hex digits of the sha256 of an array's C-ordered bytes (not its dtype or shape, which the
    manifest records beside)."""
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()


def file_sha256(path: Path) -> str:
    """64 hex digits of the sha256 of a file, read in chunks; OSError if it cannot be read."""
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def json_sha256(obj) -> str:
    """64 hex digits of ``sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")))``."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def labels_sha256(row: dict) -> str:
    """:func:`json_sha256` of a shard or manifest row without its ``labels_sha256`` and ``npz`` keys.

    JSON floats round-trip exactly, so a row read back from disk hashes as it was written.
    """
    return json_sha256({k: v for k, v in row.items() if k not in ("labels_sha256", "npz")})


def card_sha256(card: dict) -> str:
    """:func:`json_sha256` of a dataset card (``dataset.json``) without its ``card_sha256`` key."""
    return json_sha256({k: v for k, v in card.items() if k != "card_sha256"})


def shard_comment(shard: int, fingerprint: str, label_hashes: Iterable[str]) -> bytes:
    """The zip comment of a shard file: what binds it to its dataset.

    Parameters
    ----------
    shard : int
        Shard number.
    fingerprint : str
        Config fingerprint of the dataset (``DatasetConfig.fingerprint()``, covers the seed).
    label_hashes : iterable of str
        ``labels_sha256`` of the shard's rows, in index order.

    Returns
    -------
    bytes
        ASCII ``"simtest-dataset shard=N config_fingerprint=<hex> labels_sha256=<hex>"``, the last
        the sha256 of the rows' label hashes joined by newlines.
    """
    joined = hashlib.sha256("\n".join(label_hashes).encode()).hexdigest()
    return f"{FORMAT} shard={int(shard)} config_fingerprint={fingerprint} labels_sha256={joined}".encode()


def shard_path_from_row(root: Path, row: dict) -> Path:
    """The shard file of a manifest row, refusing any path outside ``root/shards``.

    Parameters
    ----------
    root : Path
        Dataset folder.
    row : dict
        A manifest row; its ``npz`` must read ``shards/shard-XXXXX.npz`` with the row's ``shard``.

    Returns
    -------
    Path
        ``root / row["npz"]``.

    Raises
    ------
    DatasetError
        If ``npz`` is absolute, climbs out with ``..``, has another form, or names another shard
        than the row's ``shard`` (the message names the index and the path).
    """
    rel = row.get("npz")
    m = _NPZ_REL.fullmatch(rel) if isinstance(rel, str) else None
    if m is None:
        raise DatasetError(f"{Path(root) / MANIFEST_NAME}: sample {row.get('index')}: npz {rel!r} is not "
                           "of the form shards/shard-XXXXX.npz inside the dataset folder: refused")
    shard = row.get("shard")
    if not (isinstance(shard, int) and not isinstance(shard, bool) and shard >= 0
            and rel == f"{SHARDS_DIR}/{shard_npz_path(Path('.'), shard).name}"):
        raise DatasetError(f"{Path(root) / MANIFEST_NAME}: sample {row.get('index')}: npz {rel!r} is not "
                           f"the file of its shard {shard!r} (expected shards/shard-"
                           f"{shard if isinstance(shard, int) else 0:05d}.npz)")
    return Path(root) / rel


def shard_npz_path(root: Path, shard: int) -> Path:
    """Path of a shard's array file, ``root/shards/shard-XXXXX.npz`` (five-digit shard number)."""
    return Path(root) / SHARDS_DIR / f"shard-{shard:05d}.npz"


def shard_json_path(root: Path, shard: int) -> Path:
    """Path of a shard's row file, ``root/shards/shard-XXXXX.json`` (marks the shard complete)."""
    return Path(root) / SHARDS_DIR / f"shard-{shard:05d}.json"


def entry_name(index: int, array: str) -> str:
    """Key of an array inside a shard ``.npz``: ``"<index:08d>/<array>"``."""
    return f"{index:08d}/{array}"


@dataclass
class ShardWriter:
    """Writes the samples of one shard in index order, then renames the shard into place.

    Samples may be added in any order; out-of-order ones wait in memory.

    Parameters
    ----------
    root : Path
        Dataset folder.
    shard : int
        Shard number.
    indices : range
        Sample indices of the shard.
    meta : dict
        Extra keys written in the shard's JSON (e.g. the config fingerprint).
    compress : bool
        Deflate the entries of :data:`DEFLATED` (the others are stored either way).
    """

    root: Path
    shard: int
    indices: range
    meta: dict = field(default_factory=dict)
    compress: bool = False
    _next: int = field(init=False, default=0)
    _pending: dict = field(init=False, default_factory=dict)
    _rows: list = field(init=False, default_factory=list)
    _zip: zipfile.ZipFile | None = field(init=False, default=None)

    @property
    def npz_path(self) -> Path:
        """Final path of the shard, ``root/shards/shard-XXXXX.npz`` (exists once complete)."""
        return shard_npz_path(self.root, self.shard)

    @property
    def tmp_path(self) -> Path:
        """Path written while the shard is incomplete: :attr:`npz_path` + ``".tmp"``."""
        p = self.npz_path
        return p.with_name(p.name + TMP_SUFFIX)

    def add(self, sample) -> bool:
        """Queue one sample; write it and any queued successors that are now in order.

        Parameters
        ----------
        sample : simtest.dataset.sample.Sample
            A sample whose ``index`` lies in :attr:`indices`.

        Returns
        -------
        bool
            True once every sample of the shard is written, the ``.npz`` renamed into place and
            its ``.json`` written; False while samples are missing.

        Raises
        ------
        DatasetError
            If the sample's index is outside the shard or was given before.
        """
        if sample.index not in self.indices:
            raise DatasetError(f"sample {sample.index} does not belong to shard {self.shard}")
        if sample.index in self._pending or sample.index < self.indices[0] + self._next:
            raise DatasetError(f"sample {sample.index} was given twice to shard {self.shard}")
        self._pending[sample.index] = sample
        while self._next < len(self.indices) and self.indices[self._next] in self._pending:
            self._write(self._pending.pop(self.indices[self._next]))
            self._next += 1
        if self._next == len(self.indices):
            self._finish()
            return True
        return False

    def _write(self, sample) -> None:
        if self._zip is None:
            self.tmp_path.parent.mkdir(parents=True, exist_ok=True)
            self._zip = zipfile.ZipFile(self.tmp_path, "w", allowZip64=True)
        arrays = {}
        for name, a in sample.arrays.items():
            a = np.asarray(a)
            info = zipfile.ZipInfo(entry_name(sample.index, name) + ".npy", date_time=_ZIP_TIME)
            deflate = self.compress and name in DEFLATED
            info.compress_type = zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED
            info.external_attr = 0o644 << 16
            with self._zip.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.ascontiguousarray(a), allow_pickle=False)
            arrays[name] = {"sha256": array_sha256(a), "dtype": str(a.dtype), "shape": list(a.shape)}
        row = {**sample.record, "index": int(sample.index), "shard": int(self.shard), "arrays": arrays}
        row["labels_sha256"] = labels_sha256(row)
        self._rows.append(row)

    def _finish(self) -> None:
        assert self._zip is not None
        self._zip.comment = shard_comment(self.shard, str(self.meta.get("config_fingerprint", "")),
                                          (r["labels_sha256"] for r in self._rows))
        self._zip.close()
        self._zip = None
        with open(self.tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(self.tmp_path, self.npz_path)
        doc = {"shard": self.shard, "npz": self.npz_path.name, "npz_sha256": file_sha256(self.npz_path),
               "npz_bytes": self.npz_path.stat().st_size, "indices": [self.indices.start, self.indices.stop],
               **self.meta, "samples": self._rows}
        atomic_write_json(shard_json_path(self.root, self.shard), doc)

    def abort(self) -> None:
        """Close and delete the partial file (a rerun redoes the shard); never raises OSError."""
        if self._zip is not None:
            try:
                self._zip.close()
            except (OSError, ValueError):  # e.g. the disk is full: the file is deleted anyway
                pass
            self._zip = None
        self.tmp_path.unlink(missing_ok=True)


def read_shard_rows(root: Path, shard: int) -> dict | None:
    """The JSON document of one shard.

    Parameters
    ----------
    root : Path
        Dataset folder.
    shard : int
        Shard number.

    Returns
    -------
    dict or None
        The shard's ``.json`` (keys ``shard``, ``npz``, ``npz_sha256``, ``npz_bytes``, ``indices``,
        ``samples`` and the writer's meta), or None if it is missing or unreadable, which marks an
        incomplete shard.
    """
    p = shard_json_path(root, shard)
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def check_shard(root: Path, shard: int, fingerprint: str, indices: range) -> list[str]:
    """What is wrong with the files of one shard (hashes and provenance; arrays not decoded).

    Checks that the row file reads, names this shard, this dataset's config ``fingerprint`` and
    exactly ``indices``; that the ``.npz`` exists, hashes to the row file's ``npz_sha256``, and
    that its zip comment names the same shard, fingerprint and label hashes; and that every row's
    ``labels_sha256`` matches its content (:func:`labels_sha256`).

    Parameters
    ----------
    root : Path
        Dataset folder.
    shard : int
        Shard number.
    fingerprint : str
        Config fingerprint of the dataset (its card's, or the config being generated).
    indices : range
        Sample indices the shard must hold.

    Returns
    -------
    list of str
        One line per problem, each naming the file; empty when the shard is sound.
    """
    npz, js = shard_npz_path(root, shard), shard_json_path(root, shard)
    doc = read_shard_rows(root, shard)
    if doc is None:
        return [f"{js}: missing or not JSON"]
    if not npz.is_file():
        return [f"{npz}: missing"]
    out = []
    if doc.get("config_fingerprint") != fingerprint:
        out.append(f"{js}: config_fingerprint {str(doc.get('config_fingerprint'))[:12]} is not this "
                   f"dataset's ({fingerprint[:12]}): a shard of another dataset (seed or config)")
    if doc.get("shard") != shard or doc.get("indices") != [indices.start, indices.stop]:
        out.append(f"{js}: names shard {doc.get('shard')!r} with indices {doc.get('indices')!r}, expected "
                   f"shard {shard} with [{indices.start}, {indices.stop}]")
    samples = doc.get("samples")
    if not isinstance(samples, list) or not all(isinstance(r, dict) for r in samples):
        return out + [f"{js}: samples: not a list of rows"]
    if [r.get("index") for r in samples] != list(indices):
        out.append(f"{js}: samples are not {indices.start}..{indices.stop - 1} in order")
    for r in samples:
        if r.get("labels_sha256") != labels_sha256(r):
            out.append(f"{js}: sample {r.get('index')}: labels differ from their labels_sha256")
    try:
        digest = file_sha256(npz)
        with zipfile.ZipFile(npz) as z:  # NotImplementedError: a damaged central directory
            head, _, rest = z.comment.decode("ascii", errors="replace").partition(" ")
    except (OSError, zipfile.BadZipFile, NotImplementedError) as exc:
        return out + [f"{npz}: unreadable: {exc}"]
    if digest != doc.get("npz_sha256"):
        out.append(f"{npz}: sha256 differs from {js.name}")
    want = shard_comment(shard, fingerprint, (str(r.get("labels_sha256")) for r in samples)).decode()
    comment = {} if head != FORMAT else dict(kv.split("=", 1) for kv in rest.split() if "=" in kv)
    got = " ".join([FORMAT] + [f"{k}={v}" for k, v in comment.items()]) if comment else "(none)"
    if got != want:
        out.append(f"{npz}: zip comment {got[:60]!r}... does not name shard {shard} of this dataset "
                   f"(config {fingerprint[:12]}) with these labels")
    return out


def read_card(root: Path) -> dict:
    """The dataset card ``root/dataset.json``.

    Parameters
    ----------
    root : Path
        Dataset folder.

    Returns
    -------
    dict
        The card (config, seed, version, counts, channels and units).

    Raises
    ------
    DatasetError
        If it is missing, unreadable or not a simtest dataset card.
    """
    p = Path(root) / CARD_NAME
    try:
        card = json.loads(p.read_text(encoding="utf-8"))
    except (FileNotFoundError, NotADirectoryError):  # no card, or ROOT is a file
        raise DatasetError(f"{p}: missing: not a simtest dataset folder") from None
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{p}: unreadable: {exc}") from None
    if not isinstance(card, dict) or card.get("format") != FORMAT:
        raise DatasetError(f"{p}: format: not a {FORMAT} card")
    if card.get("format_version") != FORMAT_VERSION:
        raise DatasetError(f"{p}: format_version: {card.get('format_version')!r} is not supported "
                           f"(this simtest reads {FORMAT_VERSION})")
    return card


def read_manifest(root: Path) -> list[dict]:
    """Rows of ``root/manifest.jsonl``, in index order.

    Parameters
    ----------
    root : Path
        Dataset folder.

    Returns
    -------
    list of dict
        One row per sample (labels, ``index``, ``shard``, per-array ``sha256``/``dtype``/``shape``);
        blank lines are skipped.

    Raises
    ------
    DatasetError
        If the manifest is missing (the dataset is incomplete) or a line is not JSON.
    """
    p = Path(root) / MANIFEST_NAME
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise DatasetError(f"{p}: missing: the dataset is incomplete (rerun `simtest dataset "
                           "generate` with the same config and --out)") from None
    rows = []
    for k, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            rows.append(json.loads(line))
        except ValueError as exc:
            raise DatasetError(f"{p}: line {k}: not JSON: {exc}") from None
    return rows


def write_manifest(root: Path, rows: Iterable[dict]) -> Path:
    """Atomically write ``root/manifest.jsonl`` (one compact JSON object per line)."""
    text = "".join(json.dumps(r, separators=(",", ":")) + "\n" for r in rows)
    return atomic_write_text(Path(root) / MANIFEST_NAME, text)


def decode_png(a: np.ndarray) -> np.ndarray:
    """The uint8 sensor image (H, W) or (H, W, 3), rows = v, of the stored ``sensor_png`` bytes
    (uint8, shape (nbytes,)); PIL.UnidentifiedImageError if they are not an image."""
    with Image.open(io.BytesIO(np.asarray(a, dtype=np.uint8).tobytes())) as im:
        return np.asarray(im)
