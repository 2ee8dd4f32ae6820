"""Scoring highlight detection against labelled bright structures: precision, recall and F1.

A frame's ground truth is a list of labelled bright structures, each of a kind (:data:`KINDS`).
The targets are the ``isolated`` ones: a single compact elliptical specular highlight on tissue,
what the isophote method can use. Labels come from hand-labelled real frames
(``tests/data/real/structures_labelled.json``, protocol in ``tests/data/real/README.md``) or from
renders (:func:`simtest.render.truth.highlight_targets`). A render's truth also tells where its light is
mostly specular reflection (:func:`simtest.render.truth.specular_pixels`): a candidate on no label there
falls on ``specular`` (a glint of a glint field, a streak or a sheen: specular, not an isolated highlight),
elsewhere on ``unlabelled``.

Matching: a candidate's BP falls on the structure whose labelled pixels it lies on, where a label map
gives them (a clipped plateau's BP may sit anywhere on it); else on the nearest structure within its
reach (radius of a disc of its area plus ``tolerance_px``, from the centroid or, for a rendered target
of several lights' BPs, from their hull and peak). Each target counts once per lobe, for the first (brightest)
candidates; more are duplicates, false positives. Precision: the fraction of candidates (or
``ok`` estimates) that are a target's first match; recall: the fraction of targets matched.

References
----------
Classical detectors reach an F1 of about 0.72 on CVC-ClinicSpec; SpecReFlow (J. Med. Imaging
2024) a pixel Dice of about 0.83. Those count pixels; these scores count highlights.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from simtest._lazy import require
from simtest.evaluate.calibration import cross_validated_confidence, ranking_auc, reliability
from simtest.geometry.angles import angle_between_deg
from simtest.geometry.cameras import PinholeCamera
from simtest.geometry.response import video_response
from simtest.harness.protocols import mesh_pose_overrides, realisation_overrides
from simtest.harness.suite import bundled_suite_names, load_suite, realisation_seed
from simtest.evaluate.operating import precision_recall
from simtest.reconstruct.detect import luma
from simtest.reconstruct.frame_verify import default_min_confidence
from simtest.reconstruct.images import load_image
from simtest.reconstruct.io import estimate_to_dict
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.rig_centroid import light_aware_with_rig
from simtest.reconstruct.settings import ReconSettings
from simtest.reconstruct.verify import RESIDUAL_MAX_REL, assess, confidence_features
from simtest.render.render import render_scene
from simtest.render.sensor import field_stop_mask
from simtest.render.truth import HighlightTarget, highlight_targets, specular_pixels
from simtest.scene import with_overrides
from simtest.scene.spec import load_scene

__all__ = ["KINDS", "TARGET_KIND", "SPECULAR_KIND", "PASSING", "TOLERANCE_PX", "Structure", "FrameScore",
           "LabelledFrame", "match_candidates", "score_frame", "pooled", "groups", "is_suite", "labelled_real_frames",
           "rendered_frames", "suite_frames", "evaluate_frames", "labeller_agreement", "confidence_rows",
           "cross_validated_report"]

#: The kinds of labelled bright structure; ``isolated`` is the target.
KINDS = ("isolated", "cluster", "streak", "instrument", "overlay", "border", "texture")
TARGET_KIND = "isolated"
#: What a render's candidate on no label falls on where its light is mostly specular reflection.
SPECULAR_KIND = "specular"
#: How far from a candidate's BP a render's specular pixel may lie for the candidate to fall on it, px: the BP's
#: pixel and its 8 neighbours (the BP is a sub-pixel peak of the smoothed frame; a geometric bound, not tuned).
SPECULAR_REACH_PX = 1
#: The statuses of a fit that passes every specularity check (``low_confidence``: below ``--min-confidence``).
PASSING = ("ok", "low_confidence")

#: Slack added to a structure's radius when matching a candidate's BP, px: the centroid's offset
#: from the brightest pixel on the small glints of 280 px frames.
TOLERANCE_PX = 2.0


@dataclass(frozen=True)
class Structure:
    """One labelled bright structure of a frame.

    Attributes
    ----------
    u, v : float
        Centroid, px (column, row; pixel centres at integer coordinates).
    area_px : float
        Area at half its height above the local background, px.
    kind : str
        One of :data:`KINDS`.
    target : HighlightTarget or None
        A rendered target's ground truth (its lights' BPs and its peak), None for a label.
    """

    u: float
    v: float
    area_px: float
    kind: str
    target: HighlightTarget | None = field(default=None, compare=False, repr=False)

    @property
    def reach_px(self) -> float:
        """The radius within which a candidate's BP falls on it: sqrt(area / pi) + slack."""
        return math.sqrt(max(self.area_px, 1.0) / math.pi) + TOLERANCE_PX

    def distance_px(self, uv) -> float:
        """Distance, px, from ``uv`` [u, v] to the centroid, or to a rendered target's hull where nearer."""
        d = math.dist((float(uv[0]), float(uv[1])), (self.u, self.v))
        return d if self.target is None else min(d, self.target.distance_px(uv))


def match_candidates(bps_px, structures: list[Structure], label_px: np.ndarray | None = None) -> list[int | None]:
    """The structure each candidate falls on (the one whose pixels hold its BP, else the nearest that
    reaches it), or None.

    Parameters
    ----------
    bps_px : array_like of shape (N, 2)
        The candidates' BPs, [u, v] px, brightest first.
    structures : list of Structure
        The frame's labels.
    label_px : ndarray of shape (H, W), int, optional
        Each pixel's structure as 1 + its index in ``structures`` (0: none), as
        :attr:`LabelledFrame.label_px`; a BP's nearest pixel on a structure matches it at distance 0.

    Returns
    -------
    list of int or None
        Index into ``structures`` per candidate.
    """
    bps = np.asarray(bps_px, dtype=np.float64).reshape(-1, 2)
    if not structures or not len(bps):
        return [None] * len(bps)
    cen = np.array([[s.u, s.v] for s in structures])
    reach = np.array([s.reach_px for s in structures])
    d = np.linalg.norm(bps[:, None, :] - cen[None, :, :], axis=2)
    for j, s in enumerate(structures):
        if s.target is not None:  # the hull of its BPs and peak, for the candidates near enough
            extent = float(np.max(np.linalg.norm(s.target.bp_px - cen[j], axis=1), initial=0.0))
            for i in np.flatnonzero(d[:, j] <= reach[j] + extent):
                d[i, j] = s.distance_px(bps[i])
    d[d > reach[None, :]] = np.inf
    if label_px is not None:  # on a structure's own pixels: that structure, wherever its peak
        c, r = np.round(np.where(np.isfinite(bps), bps, -1.0)).astype(np.int64).T
        inside = np.flatnonzero((r >= 0) & (r < label_px.shape[0]) & (c >= 0) & (c < label_px.shape[1]))
        on = label_px[r[inside], c[inside]].astype(np.int64) - 1
        d[inside[on >= 0], on[on >= 0]] = 0.0
    best = np.argmin(d, axis=1)
    return [int(j) if np.isfinite(d[i, j]) else None for i, j in enumerate(best)]


@dataclass
class FrameScore:
    """Detection scores of one frame (or pooled over frames): counts, then the ratios.

    Attributes
    ----------
    name : str
        The frame (or ``"pooled"``).
    targets : int
        Labelled targets (isolated highlights).
    candidates, candidates_tp : int
        Candidates examined, and those that are a target's first match.
    ok, ok_tp : int
        Estimates with status ``ok``, and those that are a target's first ``ok`` match.
    targets_found, targets_found_ok : int
        Targets matched by a candidate, by an ``ok`` estimate.
    ok_on : Counter
        The ``ok`` estimates by what they fall on: a kind, ``"duplicate"``, ``"specular"`` or ``"unlabelled"``.
    """

    name: str
    targets: int = 0
    candidates: int = 0
    candidates_tp: int = 0
    ok: int = 0
    ok_tp: int = 0
    targets_found: int = 0
    targets_found_ok: int = 0
    ok_on: Counter = field(default_factory=Counter)

    @staticmethod
    def _ratio(a: int, b: int) -> float | None:
        return a / b if b else None

    @staticmethod
    def _f1(p, r) -> float | None:
        return None if p is None or r is None or p + r == 0 else 2 * p * r / (p + r)

    def as_dict(self) -> dict:
        """Counts and ratios (None where a ratio has no denominator), JSON-ready."""
        pc, rc = self._ratio(self.candidates_tp, self.candidates), self._ratio(self.targets_found, self.targets)
        po, ro = self._ratio(self.ok_tp, self.ok), self._ratio(self.targets_found_ok, self.targets)
        return {"name": self.name, **{k: getattr(self, k) for k in _COUNTS},
                "precision_candidates": pc, "recall_candidates": rc, "f1_candidates": self._f1(pc, rc),
                "precision_ok": po, "recall_ok": ro, "f1_ok": self._f1(po, ro),
                "ok_on": dict(sorted(self.ok_on.items()))}


def score_frame(name: str, specularities: list[dict], structures: list[Structure],
                specular_px: np.ndarray | None = None,
                label_px: np.ndarray | None = None) -> tuple[FrameScore, list[dict]]:
    """Score one frame's estimates against its labels.

    Parameters
    ----------
    name : str
        The frame.
    specularities : list of dict
        Its estimates as in ``estimates.json`` (``bp_px``, ``status``), brightest first.
    structures : list of Structure
        Its labels.
    specular_px : ndarray of shape (H, W), bool, optional
        A render's pixels whose light is mostly specular reflection: a candidate on no label within
        :data:`SPECULAR_REACH_PX` of one falls on :data:`SPECULAR_KIND`. The scores do not read it.
    label_px : ndarray of shape (H, W), int, optional
        The structures' pixels (:func:`match_candidates`).

    Returns
    -------
    (FrameScore, list of dict)
        The scores, and per candidate ``{"bp_px", "status", "on": kind | "duplicate" | "specular" |
        "unlabelled", "tp": bool, "tp_ok": bool, "tp_pass": bool, "confidence", "target"}``
        (``tp_pass``: a target's first match among the fits that pass the checks, ``ok`` or
        ``low_confidence``: the set ``--min-confidence`` chooses from). A rendered target of k lights' highlights takes k matches as
        true positives (one a guide's lobe); it is found (recall) once.
    """
    bps = [s["bp_px"] for s in specularities]
    hit = match_candidates(bps, structures, label_px)
    sc = FrameScore(name, targets=sum(s.kind == TARGET_KIND for s in structures), candidates=len(specularities))
    found: Counter = Counter()
    found_ok: Counter = Counter()
    found_pass: Counter = Counter()
    rows = []
    for s, j in zip(specularities, hit):
        ok = s["status"] == "ok"
        passes = s["status"] in PASSING
        on = structures[j].kind if j is not None else _on_specular(specular_px, s["bp_px"])
        tp = tp_ok = tp_pass = False
        if on == TARGET_KIND:
            # a target of k lights' highlights holds k true ones (one estimate a guide's lobe)
            lobes = 1 if structures[j].target is None else len(structures[j].target.bp_px)
            if found[j] >= lobes:
                on = "duplicate"
            else:
                found[j] += 1
                tp = True
            if ok and found_ok[j] < lobes:
                found_ok[j] += 1
                tp_ok = True
            if passes and found_pass[j] < lobes:
                found_pass[j] += 1
                tp_pass = True
        sc.candidates_tp += tp
        if ok:
            sc.ok += 1
            sc.ok_tp += tp_ok
            sc.ok_on[_ok_on(tp_ok, on)] += 1
        rows.append({"bp_px": [float(v) for v in s["bp_px"]], "status": s["status"], "on": on,
                     "tp": tp, "tp_ok": tp_ok, "tp_pass": tp_pass, "confidence": s.get("confidence"), "target": j})
    sc.targets_found, sc.targets_found_ok = len(found), len(found_ok)
    return sc, rows


def _ok_on(tp_ok: bool, on: str) -> str:
    """What an ok estimate fell on: ``isolated`` (a target's first), ``duplicate`` (a target found before), else ``on``."""
    return "isolated" if tp_ok else ("duplicate" if on == TARGET_KIND else on)


def _on_specular(specular_px: np.ndarray | None, uv) -> str:
    """:data:`SPECULAR_KIND` where a pixel within :data:`SPECULAR_REACH_PX` of ``uv`` [u, v] is in ``specular_px``,
    else ``"unlabelled"``."""
    if specular_px is None or not np.all(np.isfinite(uv)):
        return "unlabelled"
    c, r, k = int(round(float(uv[0]))), int(round(float(uv[1]))), SPECULAR_REACH_PX
    near = specular_px[max(r - k, 0):max(r + k + 1, 0), max(c - k, 0):max(c + k + 1, 0)]
    return SPECULAR_KIND if near.any() else "unlabelled"


_COUNTS = ("targets", "candidates", "candidates_tp", "ok", "ok_tp", "targets_found", "targets_found_ok")


def pooled(scores: list[FrameScore]) -> FrameScore:
    """The frames' counts summed (ratios of sums, not means of ratios)."""
    out = FrameScore("pooled")
    for s in scores:
        for k in _COUNTS:
            setattr(out, k, getattr(out, k) + getattr(s, k))
        out.ok_on.update(s.ok_on)
    return out


@dataclass(frozen=True)
class LabelledFrame:
    """One frame with its labels.

    Attributes
    ----------
    name : str
        A tile id ``r{r}c{c}``, or a scene name.
    image : ndarray of shape (H, W, 3) or (H, W)
        The frame as a camera gives it (uint8).
    camera : CameraModel
        Its camera model (an assumed pinhole for the uncalibrated real frames).
    structures : list of Structure
    lights : LightRig or None
        A render's light rig; None: unknown.
    specular_px : ndarray of shape (H, W), bool, or None
        A render's pixels whose light is mostly specular reflection
        (:func:`~simtest.render.truth.specular_pixels`); None: unknown (real frames).
    label_px : ndarray of shape (H, W), int32, or None
        Each pixel's structure as 1 + its index in ``structures`` (0: none), from a labelled set's
        label map; None: structures placed by their points alone.
    normals_px : ndarray of shape (H, W, 3), or None
        A render's true unit normals, camera frame (shading normals, micro-relief included where the scene has
        it; NaN off the surface; float16, within 0.05 deg: a suite's frames are held at once); None: real frames.
    response : SensorResponse or None
        A render's video response, as its camera file gives it; None: unknown (linear).
    """

    name: str
    image: np.ndarray
    camera: object
    structures: list
    lights: object = None
    specular_px: np.ndarray | None = None
    label_px: np.ndarray | None = None
    normals_px: np.ndarray | None = None
    response: object = None


def labelled_real_frames(path, *, focal_px: float = 140.0) -> list[LabelledFrame]:
    """The frames of a hand-labelled set (``tests/data/real/structures_labelled.json``'s layout).

    Parameters
    ----------
    path : str or Path
        JSON ``{"header": {"image": file beside the JSON, "tile_px": tile side (default 280),
        "labelmap": optional image-sized 16-bit PNG beside the JSON whose pixels hold their structure's
        "index" (0: none)}, "tiles": {"r{r}c{c}": [{"u", "v", "u_peak", "v_peak", "area_px", "kind",
        "index"}, ...]}}`` in tile pixels; a structure is placed at its peak where it has one, and on its
        pixels where the label map gives them.
    focal_px : float
        The assumed pinhole's focal length, px (the frames are uncalibrated).

    Returns
    -------
    list of LabelledFrame
        In the file's order.

    Raises
    ------
    ValueError
        A missing or unreadable file, key, image or label map (or one of another size than the image), a
        tile outside the image, or a label row with a bad kind, coordinate, area or index, in one line
        naming the file, the row and the key.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        head = doc.get("header", doc)
        src = Path(head["image"])
        tiles = doc["tiles"]
        side = int(head.get("tile_px", 280))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"{path}: not a labelled set ({getattr(exc, 'strerror', None) or f'{type(exc).__name__}: {exc}'})") from None
    image_path = path.parent / src
    if not image_path.is_file():
        raise ValueError(f"{path}: key 'image': {image_path} not found")
    image = load_image(image_path)
    labels = _label_map(path, head, image.shape[:2])
    f = float(focal_px)
    K = [[f, 0.0, side / 2 - 0.5], [0.0, f, side / 2 - 0.5], [0.0, 0.0, 1.0]]
    camera = PinholeCamera(K, image_size=(side, side))
    if not isinstance(tiles, dict):
        raise ValueError(f"{path}: key 'tiles' must be an object of tile id -> list of structures, "
                         f"got {type(tiles).__name__}")
    if not (isinstance(side, int) and 3 <= side <= min(image.shape[:2])):
        raise ValueError(f"{path}: key 'tile_px': {side!r} is not a tile side within the image "
                         f"({image.shape[1]} x {image.shape[0]} px)")
    out = []
    for tile, items in tiles.items():
        m = re.fullmatch(r"r(\d+)c(\d+)", tile)
        if m is None:
            raise ValueError(f"{path}: tiles: tile id {tile!r} is not of the form r<row>c<column>")
        r0, c0 = int(m.group(1)) * side, int(m.group(2)) * side
        r1, c1 = r0 + side, c0 + side
        if r1 > image.shape[0] or c1 > image.shape[1]:
            raise ValueError(f"{path}: tiles.{tile}: rows {r0}-{r1}, columns {c0}-{c1} lie outside the "
                             f"{image.shape[1]} x {image.shape[0]} px image")
        if not isinstance(items, list):
            raise ValueError(f"{path}: tiles.{tile}: must be a list of structures, got {type(items).__name__}")
        structs = [_labelled_structure(path, f"tiles.{tile}[{i}]", s, side) for i, s in enumerate(items)]
        out.append(LabelledFrame(tile, np.ascontiguousarray(image[r0:r1, c0:c1]), camera, structs,
                                 label_px=None if labels is None else _tile_labels(path, tile, items, labels[r0:r1, c0:c1])))
    return out


def _label_map(path: Path, head: dict, shape) -> np.ndarray | None:
    """The labelled set's label map (``header.labelmap``, beside the JSON) as int64, or None without one."""
    if head.get("labelmap") is None:
        return None
    try:
        labels = load_image(file := path.parent / str(head["labelmap"]))  # a 16-bit grey PNG as stored
    except ValueError as exc:
        raise ValueError(f"{path}: key 'labelmap': {exc}") from None
    if labels.shape != tuple(shape):
        raise ValueError(f"{path}: key 'labelmap': {file} is of shape {labels.shape}, not the image's {tuple(shape)}")
    return labels.astype(np.int64)


def _tile_labels(path: Path, tile: str, items: list, labels: np.ndarray) -> np.ndarray:
    """A tile's label map as 1 + each pixel's row in ``items`` (0: none); a pixel of an index no row has: 0."""
    index = [s.get("index") for s in items]
    if not all(isinstance(k, int) and not isinstance(k, bool) and k > 0 for k in index) or len(set(index)) < len(index):
        raise ValueError(f"{path}: tiles.{tile}: with a label map every row needs its own positive integer 'index'")
    lut = np.zeros(max(int(labels.max(initial=0)), max(index, default=0)) + 1, np.int32)
    lut[index] = np.arange(1, len(index) + 1, dtype=np.int32)
    return lut[labels]


def _labelled_structure(path: Path, where: str, s, side: int) -> Structure:
    """One label row as a :class:`Structure`, or a one-line ValueError naming file, row and key."""
    if not isinstance(s, dict):
        raise ValueError(f"{path}: {where}: must be an object with 'u', 'v', 'area_px' and 'kind', got {s!r}")
    kind = s.get("kind")
    if kind not in KINDS:
        raise ValueError(f"{path}: {where}.kind: {kind!r} is not one of {KINDS}")
    # at its peak where the labels give one (a BP is a peak; a streak's centroid is not)
    keys = ("u_peak", "v_peak") if "u_peak" in s or "v_peak" in s else ("u", "v")
    vals = {}
    for key, lo, hi in ((keys[0], -0.5, side - 0.5), (keys[1], -0.5, side - 0.5), ("area_px", 1.0, float(side * side))):
        x = s.get(key)
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise ValueError(f"{path}: {where}.{key}: must be a finite number, got {x!r}")
        if not lo <= x <= hi:
            what = "px within the tile" if key != "area_px" else "px^2, 1 px to the tile's area"
            raise ValueError(f"{path}: {where}.{key}: {x!r} is outside [{lo:g}, {hi:g}] ({what})")
        vals[key] = float(x)
    return Structure(vals[keys[0]], vals[keys[1]], vals["area_px"], kind)


def labeller_agreement(path) -> dict | None:
    """How far two people agree on the target kind in a hand-labelled set: a ceiling for any
    detector scored against it.

    Parameters
    ----------
    path : str or Path
        A labelled set whose structures carry ``pass1`` and ``pass2`` (the two independent
        passes) beside the resolved ``kind``.

    Returns
    -------
    dict or None
        ``{"pass2_vs_pass1": {"precision", "recall"}, "pass1_vs_resolved": {...},
        "pass2_vs_resolved": {...}}``: each pass's ``isolated`` labels scored as detections
        against the other's (or the resolved ones); None when the passes are not recorded.
    """
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    items = [s for tile in doc.get("tiles", {}).values() for s in tile]
    if not items or not all("pass1" in s and "pass2" in s for s in items):
        return None

    def score(pred: str, truth: str) -> dict:
        p = [s[pred] == TARGET_KIND for s in items]
        t = [s[truth] == TARGET_KIND for s in items]
        both = sum(a and b for a, b in zip(p, t))
        return {"precision": both / max(sum(p), 1), "recall": both / max(sum(t), 1),
                "labelled": sum(p), "truth": sum(t)}

    return {"pass2_vs_pass1": score("pass2", "pass1"), "pass1_vs_resolved": score("pass1", "kind"),
            "pass2_vs_resolved": score("pass2", "kind")}


def rendered_frames(scene: str, *, seed: int | None = None) -> list[LabelledFrame]:
    """A render's video frame, labelled with its targets (:func:`highlight_targets`).

    Parameters
    ----------
    scene : str
        A bundled scene name or a scene TOML file.
    seed : int, optional
        Render seed (default the scene's).

    Returns
    -------
    list of LabelledFrame
        One frame; its structures are the targets (kind ``isolated``) at each target's peak,
        with its half-maximum area, and ``specular_px`` where its light is mostly specular. Other bright
        structures of a render are not labelled: a candidate there is a false positive, on ``specular``
        or ``unlabelled``.
    """
    spec = load_scene(scene)
    return [_rendered_frame(spec, seed, spec.name)]


def _rendered_frame(spec, seed: int | None, name: str) -> LabelledFrame:
    """Render ``spec`` at ``seed`` and label the video frame with its targets."""
    res = render_scene(spec, seed=seed)
    sensor = res.spec.sensor
    valid = res.mask & field_stop_mask(res.mask.shape, sensor.field_stop, sensor.field_stop_radius)
    targets = highlight_targets(res.highlights, res.specular, valid)
    structs = [Structure(float(t.peak_px[0]), float(t.peak_px[1]), float(t.area_px), TARGET_KIND, t) for t in targets]
    specular = specular_pixels(res.specular, res.linear, valid)
    normals = (res.normals if res.shading_normals is None else res.shading_normals).astype(np.float16)
    response = video_response(res.spec.sensor) if res.video is not None else None
    return LabelledFrame(name, res.frame, res.camera, structs, res.light_rig, specular, normals_px=normals,
                         response=response)


def suite_frames(suite: str, *, realisations: int | None = None, progress=None) -> list[LabelledFrame]:
    """The video frames of a rendered suite's cases, labelled with their targets.

    Parameters
    ----------
    suite : str
        A bundled suite name or a suite TOML file; every case must be rendered.
    realisations : int, optional
        Realisations per distinct setting (default the suite's), rendered at the seeds
        ``simtest validate`` gives them.
    progress : callable, optional
        Called as ``progress(done, total)`` after each render.

    Returns
    -------
    list of LabelledFrame
        Named ``<sweep>@<x>#<i>``, sweep by sweep.

    Raises
    ------
    ValueError
        The suite cannot be read, or a case is not rendered.
    """
    s = load_suite(suite)
    if realisations is not None:
        s = s.with_overrides(realisations=realisations)
    cases = s.distinct_cases
    for c in cases:
        if c.protocol != "rendered":
            raise ValueError(f"{s.source}: case {c.id} is a {c.protocol!r} case; detection is scored on "
                             "rendered cases only")
    total = sum(c.realisations for c in cases)
    frames: list[LabelledFrame] = []
    for c in cases:
        spec = with_overrides(load_scene(c.scene), c.scene_setting.scene_overrides(mesh_pose_overrides))
        for i in range(c.realisations):
            over = realisation_overrides(c.scene_setting, realisation_seed(s.seed, c.key, i))
            frames.append(_rendered_frame(with_overrides(spec, over), over["render.seed"], f"{c.id}#{i}"))
            if progress is not None:
                progress(len(frames), total)
    return frames


def is_suite(source: str) -> bool:
    """Whether ``source`` names a suite (a bundled suite, or a TOML file with ``[suite]``), not a scene."""
    p = Path(source)
    if p.suffix == ".toml" and p.is_file():
        try:
            return "suite" in tomllib.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            return False
    return not p.suffix and source in bundled_suite_names()


def groups(frames_out: list[dict]) -> list[dict]:
    """Pooled scores per group of frames named ``<group>@...`` (a suite's sweeps), in order."""
    by: dict[str, list[FrameScore]] = {}
    for f in frames_out:
        g = f["name"].split("@", 1)[0]
        sc = FrameScore(g, **{k: f[k] for k in _COUNTS}, ok_on=Counter(f["ok_on"]))
        by.setdefault(g, []).append(sc)
    return [pooled(v).as_dict() | {"name": g, "frames": len(v)} for g, v in by.items()]


def _default_floor(frames: list[LabelledFrame], settings) -> float | None:
    """The ``--min-confidence`` the run's frames got (None where it differs among them)."""
    if settings.min_confidence is not None:
        return settings.min_confidence
    floors = {default_min_confidence(fr.image, fr.lights) for fr in frames}
    return floors.pop() if len(floors) == 1 else None


def evaluate_frames(frames: list[LabelledFrame], settings=None, *, keep: list | None = None,
                    light_aware: bool = False, workers: int = 1, progress=None) -> dict:
    """Reconstruct every frame with ``settings`` (default: ``reconstruct``'s) and score it.

    Parameters
    ----------
    frames : list of LabelledFrame
        The frames and their labels.
    settings : ReconSettings, optional
        Default :meth:`ReconSettings.for_frames`.
    keep : list, optional
        Where given, each frame's estimates (``Estimates``) are appended to it, in frame order:
        :func:`cross_validated_report` takes them instead of reconstructing the frames again.
    light_aware : bool
        Score what ``simtest reconstruct`` gives with a render's camera file: its response, then the light-aware
        step under its rig (:func:`~simtest.reconstruct.rig_centroid.light_aware_with_rig`), whose statuses and
        recommended normals are scored. False: the detection alone (the rig, no response, no fits).
    workers : int
        Worker processes for the light-aware fits of each frame (the results do not depend on it).
    progress : callable, optional
        Called as ``progress(done, total)`` after each frame.

    Returns
    -------
    dict
        ``{"frames": [FrameScore.as_dict() + {"candidates_detail": [...], "missed_targets_ok": [[u, v], ...],
        "missed_by": {status: n}}], "pooled", "missed_by", "settings", "normal_error_deg": {on: {"n", "median",
        "p90"}}, ...}``; a missed target is one no ``ok`` estimate found, counted by the status of the first candidate
        on it (or ``"no candidate"``); with ``normals_px``, each row's ``error_deg`` (deg; ok rows on the surface, else None).
    """
    settings = settings or ReconSettings.for_frames()
    scores, frames_out = [], []
    for done, fr in enumerate(frames, 1):
        response = fr.response if light_aware else None
        ests = reconstruct(fr.image, fr.camera, settings=settings, lights=fr.lights, response=response)
        if keep is not None:
            keep.append(ests)
        rows_of = ests if not light_aware or fr.lights is None else light_aware_with_rig(
            fr.image, ests, fr.camera, fr.lights, cubic=False, response=response, workers=workers)  # (as the CLI)
        specs = [estimate_to_dict(e) for e in rows_of]
        sc, rows = score_frame(fr.name, specs, fr.structures, fr.specular_px, fr.label_px)
        if fr.normals_px is not None:  # the recommended normal's angle to the truth at its BP
            for s, r in zip(specs, rows):
                r["error_deg"] = _normal_error_deg(s, fr.normals_px) if s["status"] == "ok" else None
        scores.append(sc)
        missed, why = [], Counter()  # the targets no ok estimate found, by the first candidate's status on them
        for j, s in enumerate(fr.structures):
            if s.kind == TARGET_KIND and not any(r["tp_ok"] and r["target"] == j for r in rows):
                missed.append([s.u, s.v])
                why[next((r["status"] for r in rows if r["target"] == j), "no candidate")] += 1
        frames_out.append(sc.as_dict() | {"not_examined": ests.n_unexamined, "candidates_detail": rows,
                                          "missed_targets_ok": missed, "missed_by": dict(why)})
        if progress is not None:
            progress(done, len(frames))
    cand = [(f["name"], r) for f in frames_out for r in f["candidates_detail"] if r["confidence"] is not None]
    conf = np.array([r["confidence"] for _, r in cand], dtype=np.float64)
    tp = np.array([r["tp"] for _, r in cand], dtype=bool)
    # the confidence's analyses read every fit that passes the checks, whatever the default C
    passing = np.array([r["status"] in PASSING for _, r in cand], dtype=bool)
    tp_pass = np.array([r["tp_pass"] for _, r in cand], dtype=bool)
    statuses = Counter(r["status"] for f in frames_out for r in f["candidates_detail"])
    errors: dict[str, list[float]] = {}  # what an ok estimate fell on -> its normals' errors (renders), deg
    for r in (r for f in frames_out for r in f["candidates_detail"] if r.get("error_deg") is not None):
        errors.setdefault(_ok_on(r["tp_ok"], r["on"]), []).append(r["error_deg"])
    pool = pooled(scores).as_dict()
    return {"frames": frames_out, "pooled": pool, "settings": settings.to_dict(), "light_aware": light_aware,
            "statuses": dict(sorted(statuses.items())),
            "missed_by": dict(sum((Counter(f["missed_by"]) for f in frames_out), Counter()).most_common()),
            "reliability": {"candidates": reliability(conf, tp), "ok": reliability(conf[passing], tp[passing])},
            "precision_recall": precision_recall(conf[passing], tp_pass[passing], pool["targets"], target_ids=[
                (name, r["target"]) for name, r in cand if r["status"] in PASSING]),  # a target is a frame's
            "default_min_confidence": _default_floor(frames, settings),
            "normal_error_deg": {on: {"n": len(e), "median": float(np.median(e)), "p90": float(np.percentile(e, 90))}
                                 for on, e in sorted(errors.items())},
            "confidence_vs_error": _rank_correlation([r for f in frames_out for r in f["candidates_detail"]])}


def _rank_correlation(rows: list[dict]) -> dict | None:
    """Spearman's rank correlation of the ok rows' confidence with their normals' error (``{"n", "rho", "p"}``;
    positive: the more confident, the worse the normal); None under three rows or where either is constant."""
    pairs = np.array([(r["confidence"], r["error_deg"]) for r in rows
                      if r.get("error_deg") is not None and r.get("confidence") is not None], np.float64).reshape(-1, 2)
    if len(pairs) < 3 or np.ptp(pairs, axis=0).min() == 0:
        return None
    got = require("scipy.stats").spearmanr(pairs[:, 0], pairs[:, 1])
    return {"n": len(pairs), "rho": float(got.statistic), "p": float(got.pvalue)}


def _normal_error_deg(spec: dict, normals_px: np.ndarray) -> float | None:
    """The angle (deg) between an estimate's recommended normal and the true normal at the pixel of its BP
    (None where the BP falls off the image or the surface)."""
    u, v = (int(round(float(x))) for x in spec["bp_px"])
    h, w = normals_px.shape[:2]
    if spec.get("normal") is None or not (0 <= u < w and 0 <= v < h) or not np.isfinite(normals_px[v, u]).all():
        return None
    return float(angle_between_deg(np.asarray(spec["normal"], dtype=np.float64), normals_px[v, u].astype(np.float64)))


def confidence_rows(frames: list[LabelledFrame], settings=None, *,
                    verified: list | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The confidence features and labels of every fit of the frames in :data:`PASSING`.

    ``verified``: each frame's estimates with the checks where the caller has them
    (:func:`evaluate_frames`' ``keep``); else each frame is reconstructed for them.

    Returns
    -------
    X : ndarray of shape (N, 5)
        Features (:func:`~simtest.reconstruct.verify.confidence_features`).
    y : ndarray of bool, shape (N,)
        True where the candidate is a target's first match.
    group : ndarray of int, shape (N,)
        Index of its frame (for cross-validation by frame).
    """
    settings = (settings or ReconSettings.for_frames()).replace(verify=False)
    xs, ys, gs = [], [], []
    for g, fr in enumerate(frames):
        fits = reconstruct(fr.image, fr.camera, settings=settings, lights=fr.lights)
        if not fits:
            continue
        ev, res, _ = assess(fr.image, luma(fr.image), fits, full_scale=255.0 if fr.image.dtype == np.uint8
                            else float(fr.image.max()), camera=fr.camera, lights=fr.lights)
        ests = verified[g] if verified is not None else reconstruct(
            fr.image, fr.camera, settings=settings.replace(verify=True), lights=fr.lights)
        _, rows = score_frame(fr.name, [estimate_to_dict(e) for e in ests], fr.structures, None, fr.label_px)
        # each verified estimate's row of the unverified fits (a broad lobe's, measured on a wider
        # background, has none: the unverified frame has no verdict to look for one)
        at = {tuple(e.bp_px): k for k, e in enumerate(fits)}
        row = np.array([at.get(tuple(e.bp_px), -1) for e in ests], np.int64)
        fitted = np.array([e.status in PASSING for e in ests], dtype=bool) & (row >= 0)
        X = confidence_features(ev, np.where(np.isfinite(res), res, RESIDUAL_MAX_REL))
        xs.append(X[row[fitted]])
        ys.append(np.array([r["tp"] for r in rows], dtype=bool)[fitted])
        gs.append(np.full(int(fitted.sum()), g))
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(gs)


def cross_validated_report(frames: list[LabelledFrame], *, verified: list | None = None) -> dict:
    """Leave-one-frame-out confidences of the passing fits, their ranking AUC and reliability.

    Returns
    -------
    dict
        ``{"n", "auc", "reliability": [...]}``.
    """
    X, y, group = confidence_rows(frames, verified=verified)
    cv = cross_validated_confidence(X, y, group)
    return {"n": int(len(y)), "auc": ranking_auc(cv, y), "reliability": reliability(cv, y)}
