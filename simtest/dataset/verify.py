"""``simtest dataset verify DIR``: check every shard and manifest entry of a dataset."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from simtest.dataset.shards import (CARD_NAME, MANIFEST_NAME, SHARDS_DIR, TMP_SUFFIX, DatasetError,
                                    array_sha256, card_sha256, check_shard, decode_png, entry_name,
                                    file_sha256, json_sha256, labels_sha256, read_card, read_manifest,
                                    read_shard_rows, shard_json_path, shard_npz_path, shard_path_from_row)

__all__ = ["UNIT_NORMAL_TOL", "VerifyReport", "verify"]

#: |‖n‖ - 1| allowed for a stored normal: far above float32 rounding (~1e-7), far below an
#: unnormalised silhouette average (< 0.999).
UNIT_NORMAL_TOL = 1e-4

#: Largest n . ray (unit ray through the pixel centre) accepted for a stored normal: about 3 deg past
#: grazing, as a silhouette pixel's footprint average may lean, yet catching flipped normals.
FACING_TOL = 0.05

_MAX_PROBLEMS = 50


@dataclass
class VerifyReport:
    """Result of :func:`verify`.

    Attributes
    ----------
    root : Path
        The dataset folder checked.
    samples : int
        Samples checked.
    shards : int
        Shard files checked.
    problems : list of str
        One line per problem (``<path>: <what>``); empty when the dataset is sound.
    """

    root: Path
    samples: int = 0
    shards: int = 0
    problems: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when no problem was found."""
        return not self.problems

    def add(self, msg: str) -> None:
        """Record one problem, one line ``<path>: <what>``."""
        self.problems.append(msg)


_EXPECT = {"sensor_png": ("uint8", 1), "linear": ("float32", 2), "specular": ("float32", 2),
           "normals": ("float32", 3), "depth": ("float32", 2), "mask": ("bool", 2), "highlight_mask": ("bool", 2)}


def _check_sample(rep: VerifyReport, where: str, row: dict, arrays: dict) -> None:
    w, h = row.get("image_size", [None, None])
    for name, (dtype, ndim) in _EXPECT.items():
        if name not in arrays:
            rep.add(f"{where}: array {name!r} missing")
            continue
        a = arrays[name]
        if str(a.dtype) != dtype or a.ndim != ndim:
            rep.add(f"{where}: {name}: dtype/rank {a.dtype}/{a.ndim}, expected {dtype}/{ndim}")
            continue
        if name != "sensor_png":
            want = (h, w, 3) if name == "normals" else (h, w)
            if tuple(a.shape) != want:
                rep.add(f"{where}: {name}: shape {tuple(a.shape)}, expected {want} (image_size)")
    if any(n not in arrays for n in _EXPECT):
        return
    mask = arrays["mask"]
    try:
        img = decode_png(arrays["sensor_png"])
    except Exception as exc:  # noqa: BLE001 - any decoder failure is a problem to report
        rep.add(f"{where}: sensor_png: not a PNG: {exc}")
    else:
        if img.dtype != np.uint8 or img.shape[:2] != mask.shape:
            rep.add(f"{where}: sensor_png: decodes to {img.dtype} {img.shape}, expected uint8 {mask.shape}")
    n = arrays["normals"]
    if n.shape[:2] == mask.shape:
        inside = n[mask]
        if not np.all(np.isfinite(inside)):
            rep.add(f"{where}: normals: non-finite values inside the mask")
        else:
            err = np.abs(np.linalg.norm(inside.astype(np.float64), axis=-1) - 1.0)
            if err.size and err.max() > UNIT_NORMAL_TOL:
                rep.add(f"{where}: normals: not unit inside the mask (max |norm - 1| = {err.max():.2e})")
            K = np.asarray(row.get("K", np.eye(3)), dtype=np.float64)
            v, u = np.nonzero(mask)
            rays = np.stack([u, v, np.ones_like(u)], -1).astype(np.float64) @ np.linalg.inv(K).T
            rays /= np.linalg.norm(rays, axis=1, keepdims=True)
            away = np.sum(inside.astype(np.float64) * rays, axis=1) > FACING_TOL
            if np.any(away):
                rep.add(f"{where}: normals: {int(away.sum())} normals do not face the camera "
                        f"(n . ray > {FACING_TOL} at the pixel centre)")
        if np.any(n[~mask] != 0):
            rep.add(f"{where}: normals: non-zero outside the mask")
    d = arrays["depth"]
    if d.shape == mask.shape and (not np.all(np.isfinite(d[mask])) or np.any(d[mask] <= 0)):
        rep.add(f"{where}: depth: non-finite or non-positive inside the mask")
    for hl in row.get("highlights", []):
        nn = np.asarray(hl.get("normal", [np.nan] * 3), dtype=np.float64)
        if not np.all(np.isfinite(nn)) or abs(np.linalg.norm(nn) - 1.0) > UNIT_NORMAL_TOL:
            rep.add(f"{where}: highlight normal {hl.get('normal')} is not a unit vector")


def verify(root, *, check_arrays: bool = True) -> VerifyReport:
    """Check a dataset folder.

    The card (``card_sha256``, ``manifest_sha256``, ``config_fingerprint`` against its config: a damaged
    fingerprint is one problem of the card); the manifest (samples 0 .. count-1 once each, each naming
    its shard exactly as ``shards/shard-XXXXX.npz``); ``shards/`` holds nothing else and no spool or
    temporary file is left; every shard's fingerprint, label hashes, sha256 and zip comment
    (:func:`~simtest.dataset.shards.check_shard`); every array's sha256, dtype and shape against the
    manifest; shapes against the image size; normals unit, facing the camera (``n . ray <= FACING_TOL``,
    ray ``K^{-1} (u, v, 1)``) inside the mask and zero outside; depth positive inside the mask; the PNG
    decodes.

    Parameters
    ----------
    root : path
        Dataset folder.
    check_arrays : bool
        Load and check every array (default); False checks only files, counts and hashes.

    Returns
    -------
    VerifyReport
        ``report.ok`` is True when nothing is wrong. Nothing is raised for a bad dataset: every
        problem is a line naming the file, and checking stops after 50.
    """
    root = Path(root)
    rep = VerifyReport(root=root)
    try:
        card = read_card(root)
        rows = read_manifest(root)
    except DatasetError as exc:
        rep.add(str(exc))
        return rep
    try:
        _verify(rep, root, card, rows, check_arrays)
    except _TooMany:
        rep.add("... too many problems; stopped")
    return rep


class _TooMany(Exception):
    pass


def _verify(rep: VerifyReport, root: Path, card: dict, rows: list, check_arrays: bool) -> None:
    card_path, man_path = root / CARD_NAME, root / MANIFEST_NAME

    def add(msg: str) -> None:
        rep.add(msg)
        if len(rep.problems) >= _MAX_PROBLEMS:
            raise _TooMany

    count, shard_size, n_shards = card.get("count"), card.get("shard_size"), card.get("n_shards")
    fp = card.get("config_fingerprint")
    if not (isinstance(count, int) and isinstance(shard_size, int) and shard_size > 0
            and isinstance(n_shards, int) and isinstance(fp, str)):
        add(f"{card_path}: count, shard_size, n_shards or config_fingerprint missing or not valid")
        return
    if "card_sha256" not in card:
        add(f"{card_path}: no card_sha256 (a card written by an older simtest, or the key was removed): rerun "
            "`simtest dataset generate` with the same config and --out to rewrite the card (nothing is rendered again)")
    elif card.get("card_sha256") != card_sha256(card):
        add(f"{card_path}: a value differs from its card_sha256: the card was edited or damaged")
    if "manifest_sha256" in card:
        try:
            if file_sha256(man_path) != card["manifest_sha256"]:
                add(f"{man_path}: sha256 differs from {CARD_NAME}'s manifest_sha256: the manifest "
                    "was edited or damaged")
        except OSError as exc:
            add(f"{man_path}: unreadable: {exc}")
    fp = _shard_fingerprint(add, root, card, fp, n_shards)
    if card.get("status") != "complete":
        add(f"{card_path}: status is {card.get('status')!r}, not 'complete'")
    bad_rows = [k for k, r in enumerate(rows, 1) if not isinstance(r, dict)]
    if bad_rows:
        add(f"{man_path}: line {bad_rows[0]}: not a JSON object")
        rows = [r for r in rows if isinstance(r, dict)]
    indices = [r.get("index") for r in rows]
    if indices != list(range(count)):
        dup = len(indices) - len(set(map(str, indices)))
        add(f"{man_path}: {len(rows)} rows ({dup} duplicated), expected indices 0..{count - 1} in order")
    counts = card.get("counts", {})
    if not isinstance(counts, dict) or counts.get("samples") != len(rows):
        add(f"{card_path}: counts.samples = {counts.get('samples') if isinstance(counts, dict) else counts}, "
            f"manifest has {len(rows)}")
    variants = sorted({str(r.get("variant")) for r in rows})
    if len(variants) > 1:
        add(f"{man_path}: samples rendered with several Mitsuba variants {variants}: "
            "the dataset is not reproducible bit for bit (pin `variant` in the config)")
    by_shard: dict = {}
    for r in rows:
        try:
            shard_path_from_row(root, r)
        except DatasetError as exc:
            add(str(exc))
            continue
        by_shard.setdefault(r.get("shard"), []).append(r)
    named = sorted(by_shard)  # ints: shard_path_from_row refused every other kind
    if named != list(range(n_shards)):
        add(f"{man_path}: rows name shards {_ranges(named)}, expected 0..{n_shards - 1}")

    for s in range(n_shards):
        rep.shards += 1
        want = range(s * shard_size, min(count, (s + 1) * shard_size))
        for msg in check_shard(root, s, fp, want):
            add(msg)
        npz = shard_npz_path(root, s)
        doc = read_shard_rows(root, s)
        if doc is None or not npz.is_file():
            continue
        try:
            _verify_shard(add, rep, npz, doc, {r["index"]: r for r in by_shard.get(s, [])}, check_arrays)
        except _TooMany:
            raise
        except Exception as exc:  # noqa: BLE001 - a damaged file is a problem to report, not a crash
            add(f"{npz}: unreadable: {type(exc).__name__}: {exc}")
    standard = {f(root, s).name for s in range(n_shards) for f in (shard_npz_path, shard_json_path)}
    for p in list((root / SHARDS_DIR).glob("*")) + list(root.glob("*")):
        if p.name.endswith(TMP_SUFFIX):
            add(f"{p}: temporary file left over")
        elif p.parent.name == SHARDS_DIR and p.name not in standard:
            add(f"{p}: unexpected file in {SHARDS_DIR}/ (the shards are shard-00000.npz .. "
                f"{shard_npz_path(root, max(n_shards - 1, 0)).name} with their .json)")
        elif p.parent == root and p.name == "spool":
            add(f"{p}: spooled samples left over: the generation did not finish (rerun it)")


def _ranges(nums: list) -> str:
    """``[0, 1, 2, 5, 7, 8]`` as ``"0-2, 5, 7-8"`` (at most 10 runs shown)."""
    runs: list[list[int]] = []
    for n in nums:
        if runs and n == runs[-1][1] + 1:
            runs[-1][1] = n
        else:
            runs.append([n, n])
    text = ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in runs[:10])
    return text + (", ..." if len(runs) > 10 else "") if runs else "none"


def _shard_fingerprint(add, root: Path, card: dict, fp: str, n_shards: int) -> str:
    """The config fingerprint the shards are checked against, reporting a damaged card once.

    The card's ``config_fingerprint`` must be its config's sha256, else one problem and the config's is
    used; if two or more shards all name one other fingerprint, the card does not belong to them: one
    problem, and theirs is used.
    """
    card_path = root / CARD_NAME
    try:
        of_config = json_sha256(card.get("config"))
    except (TypeError, ValueError):
        of_config = None
    if of_config is not None and of_config != fp:
        add(f"{card_path}: config_fingerprint {fp[:12]} is not the fingerprint of the card's config "
            f"({of_config[:12]}): the card was edited or damaged; rerun `simtest dataset generate` "
            "with the dataset's config and --out to repair it")
        fp = of_config
    named = set()
    for s in range(n_shards):
        doc = read_shard_rows(root, s)
        named.add(doc.get("config_fingerprint") if isinstance(doc, dict) else None)
    named.discard(None)
    if n_shards >= 2 and len(named) == 1 and fp not in named:
        theirs = str(next(iter(named)))
        add(f"{card_path}: its config (fingerprint {fp[:12]}) is not the one all {n_shards} shards were "
            f"made with ({theirs[:12]}): the card was edited or replaced")
        fp = theirs
    return fp


def _verify_shard(add, rep: VerifyReport, npz: Path, doc: dict, manifest_rows: dict, check_arrays: bool) -> None:
    """Check the entries of one shard file against the manifest rows (reads every array)."""
    with np.load(npz, allow_pickle=False) as z:
        expected_keys = set()
        for srow in doc.get("samples", []):
            i = srow.get("index")
            where = f"{npz}: sample {i}"
            mrow = manifest_rows.get(i)
            if mrow is None:
                add(f"{where}: not in the manifest")
                continue
            if {k: v for k, v in mrow.items() if k != "npz"} != srow:
                add(f"{where}: manifest row differs from the shard's row")
            if mrow.get("labels_sha256") != labels_sha256(mrow):
                add(f"{where}: manifest labels differ from their labels_sha256")
            arrays = {}
            for name, info in mrow.get("arrays", {}).items():
                key = entry_name(i, name)
                expected_keys.add(key)
                if key not in z.files:
                    add(f"{where}: entry {key!r} missing")
                    continue
                try:
                    a = z[key]
                except Exception as exc:  # noqa: BLE001 - CRC error, truncated entry, bad header
                    add(f"{where}: {name}: unreadable entry: {type(exc).__name__}: {exc}")
                    continue
                if array_sha256(a) != info.get("sha256"):
                    add(f"{where}: {name}: sha256 mismatch")
                if str(a.dtype) != info.get("dtype") or list(a.shape) != info.get("shape"):
                    add(f"{where}: {name}: {a.dtype} {list(a.shape)} but the manifest says "
                        f"{info.get('dtype')} {info.get('shape')}")
                arrays[name] = a
            if check_arrays:
                before = len(rep.problems)
                _check_sample(rep, where, mrow, arrays)
                if len(rep.problems) >= _MAX_PROBLEMS and len(rep.problems) > before:
                    raise _TooMany
            rep.samples += 1
        extra = set(z.files) - expected_keys
        if extra:
            add(f"{npz}: {len(extra)} entries not in the manifest, e.g. {sorted(extra)[0]!r}")
