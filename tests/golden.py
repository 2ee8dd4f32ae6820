"""Stored outputs of the reconstruction on pinned inputs ("results unchanged for the same settings").

Each case is an input image (a file under tests/data, or a frame built from a fixed seed) and an
explicit set of settings (so that a change of the defaults does not change the case). Its golden
file ``tests/data/golden/<case>.json.gz`` holds a compact summary of every estimate (BP, status, ROI,
per isovalue: point count, residual, N+ and N-, cone axis, eigenvalue gap; the joint cone axis):
the outputs of the code as it was when the file was written. ``tests/test_golden.py`` checks that
the current code reproduces them.

Regenerate (only in a commit that says why the results changed)::

    python tests/golden.py            # every case
    python tests/golden.py CASE ...   # some cases

Hold a change to the accuracy tolerance (:mod:`simtest.reconstruct.compare`)::

    python tests/golden.py --snapshot /tmp/before    # on the code before the change
    python tests/golden.py --compare /tmp/before     # after it: status changes, normals moved

Inputs: the real tiles of tests/data/real with their assumed f = 140 px pinhole; the sensor
images of the bundled scenes rendered with each scene's own seed, pinned as PNG under
tests/data/golden/renders (with their K in renders.json, written by ``python tests/golden.py
--renders``, which needs Mitsuba); the bench's 10-highlight 1350 x 1080 frame (seed 0), also with
2 % Gaussian read noise (seed 12); the bench's 100 x 100 px highlight through ``reconstruct_roi``
(the harness' path); and the Hyper-Kvasir banner.
"""

from __future__ import annotations

import gzip
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
DATA = ROOT / "data"
GOLDEN = DATA / "golden"
RENDERS = GOLDEN / "renders"
REAL = DATA / "real"

#: The settings of the code before the defaults for real frames (issue 9): t = 0.1 relative to
#: the BP, detection at 0.7 x full scale.
PAPER = {"isovalue": [0.1], "normalise": "bp", "detection": "full_scale", "smooth_sigma_px": 0.0}
#: The README's settings for real tissue.
LOCAL = {"isovalue": [0.5, 0.7], "normalise": "local", "detection": "full_scale", "smooth_sigma_px": 0.0,
         "min_confidence": 0.0}
#: reconstruct's defaults for whole frames (local peaks, auto normalisation and smoothing), as
#: of the commit that introduced them; spelled out so that a later change of the defaults does
#: not change the case (the minimum confidence of their day: 0, every fit that passes the checks).
DEFAULTS = {"isovalue": [0.7, 0.85], "normalise": "auto", "detection": "local_peak", "smooth_sigma_px": None,
            "min_confidence": 0.0}
NESTED = {"isovalue": [0.1, 0.3, 0.5], "normalise": "bp", "detection": "full_scale", "smooth_sigma_px": 0.0}


def _read_rgb(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return img


def _real_K() -> np.ndarray:
    return np.array(json.loads((REAL / "intrinsics_assumed_f140.json").read_text())["K"], dtype=float)


def noisy_frame():
    """The bench's frame with 2 % read noise (seed 12)."""
    from benchmarks.inputs import noisy_frame as bench_noisy_frame

    return bench_noisy_frame()


def banner_K() -> np.ndarray:
    """An assumed pinhole for the banner: f = 140 px (as for the 280 px tiles), centre of the image."""
    return np.array([[140.0, 0, 1119.5], [0, 140.0, 419.5], [0, 0, 1]])


def cases() -> dict[str, tuple]:
    """name -> (loader returning (image, K, extra kwargs), settings, function name)."""
    out = {}
    for tile in sorted(REAL.glob("hyperkvasir_tile_*.png")):
        stem = tile.stem.replace("hyperkvasir_tile_", "tile_")
        for tag, st in (("paper", PAPER), ("local", LOCAL), ("defaults", DEFAULTS)):
            out[f"{stem}_{tag}"] = (lambda p=tile: (_read_rgb(p), _real_K(), {}), st, "reconstruct")
    if (RENDERS / "renders.json").exists():
        meta = json.loads((RENDERS / "renders.json").read_text())
        for name, m in sorted(meta.items()):
            load = (lambda n=name, m=m: (_read_rgb(RENDERS / f"{n}.png"), np.array(m["K"]), {}))
            out[f"render_{name}_paper"] = (load, PAPER, "reconstruct")
            out[f"render_{name}_nested"] = (load, NESTED, "reconstruct")
            out[f"render_{name}_defaults"] = (load, DEFAULTS, "reconstruct")

    def frame():
        from benchmarks.inputs import synthetic_frame

        f, K, _ = synthetic_frame()
        return f, K, {}

    def noisy():
        f, K, _ = noisy_frame()
        return f, K, {}

    def noisy_smooth():
        f, K, _ = noisy_frame()
        return f, K, {"smooth_sigma_px": 2.0}

    def roi():
        from benchmarks.inputs import synthetic_roi_image

        img, K, bp, _ = synthetic_roi_image()
        return img, K, {"bp_uv": bp}

    out["frame10_paper"] = (frame, PAPER, "reconstruct")
    out["frame10_noise2_paper"] = (noisy, PAPER, "reconstruct")
    out["frame10_noise2_smooth2_paper"] = (noisy_smooth, PAPER, "reconstruct")
    out["frame10_defaults"] = (frame, DEFAULTS, "reconstruct")
    out["frame10_noise2_defaults"] = (noisy, DEFAULTS, "reconstruct")
    out["roi100_nested"] = (roi, NESTED, "reconstruct_roi")
    banner = REAL / "hyperkvasir_banner.jpg"
    if banner.exists():
        load = lambda: (_read_rgb(banner), banner_K(), {})  # noqa: E731
        out["banner_paper"] = (load, PAPER, "reconstruct")
        out["banner_local"] = (load, LOCAL, "reconstruct")
        out["banner_defaults"] = (load, DEFAULTS, "reconstruct")
    return out


def _f(x):
    return None if x is None else np.asarray(x, dtype=float).tolist()


def summarise(estimates) -> list[dict]:
    """Compact, JSON-able summary of a list of SpecularityEstimate (floats exact as repr)."""
    rows = []
    for e in estimates:
        rows.append({
            "bp": _f(e.bp_px), "status": e.status, "saturated": bool(e.saturated),
            "roi": [int(v) for v in e.roi], "bp_intensity": float(e.bp_intensity),
            "isophotes": [{
                "t": r.isovalue, "status": r.status,
                "n": None if r.points_uv is None else int(len(r.points_uv)),
                "closed": bool(r.closed), "residual_px": r.fit_residual_px,
                "paper": _f(r.normals_paper), "paper_selected_index": r.paper_selected_index,
                "cone_axis": _f(r.cone_axis), "gap": r.eigenvalue_gap,
            } for r in e.isophotes],
            "joint": _f(e.joint_cone_axis),
        })
    return rows


def run_case(name: str) -> list[dict]:
    """Run one case with the current code and summarise it."""
    from simtest.reconstruct import pipeline

    load, settings, fn = cases()[name]
    img, K, extra = load()
    call = getattr(pipeline, fn)
    kw = {k: v for k, v in settings.items() if k != "isovalue"}
    if fn == "reconstruct_roi":
        kw.pop("detection")
    kw.update(extra)  # a case's own smoothing replaces the settings'
    ests = call(img, K, settings["isovalue"], **kw)
    return summarise([ests] if fn == "reconstruct_roi" else ests)


def golden_path(name: str) -> Path:
    """The golden file of a case: gzipped JSON (the banner's is 700 kB as text)."""
    return GOLDEN / f"{name}.json.gz"


def read_golden(name: str) -> list[dict]:
    """The stored summary of a case."""
    with gzip.open(golden_path(name), "rt", encoding="ascii") as fh:
        return json.load(fh)


def write_golden(name: str, rows: list[dict]) -> None:
    """Store a case's summary (gzip with mtime 0: the same rows give the same bytes)."""
    data = (json.dumps(rows, separators=(",", ":")) + "\n").encode("ascii")
    golden_path(name).write_bytes(gzip.compress(data, mtime=0))


def write_renders() -> None:
    """Render every bundled scene with its own seed; pin the sensor images and K (needs Mitsuba)."""
    import cv2

    from simtest.render.render import render_scene
    from simtest.scene.spec import load_scene

    RENDERS.mkdir(parents=True, exist_ok=True)
    meta = {}
    for p in sorted((ROOT.parent / "scenes").glob("*.toml")):
        spec = load_scene(p)
        res = render_scene(spec)
        cv2.imwrite(str(RENDERS / f"{p.stem}.png"), res.sensor)
        meta[p.stem] = {"K": res.K.tolist(), "seed": int(res.seed),
                        "highlights": [{"bp_px": np.asarray(h.bp_px, float).tolist(),
                                        "normal": np.asarray(h.normal, float).tolist()}
                                       for h in res.highlights]}
    (RENDERS / "renders.json").write_text(json.dumps(meta, indent=1) + "\n")


def as_rows(summary: list[dict]) -> list[dict]:
    """A case's summary as the rows :func:`simtest.reconstruct.compare.compare_estimates` takes."""
    rows = []
    for r in summary:
        iso = r["isophotes"][0] if r["isophotes"] else {}
        pair, idx = iso.get("paper"), iso.get("paper_selected_index")
        rows.append({"bp_px": r["bp"], "status": r["status"], "normals": {
            "cone_axis": iso.get("cone_axis"), "joint_cone_axis": r["joint"],
            "paper_selected": None if pair is None or idx is None else pair[idx]}})
    return rows


def snapshot(folder: Path, names=None) -> None:
    """Write every case's current summary under ``folder`` (before a change)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in names or sorted(cases()):
        data = json.dumps(run_case(name), separators=(",", ":")) + "\n"
        (folder / f"{name}.json.gz").write_bytes(gzip.compress(data.encode("ascii"), mtime=0))


def compare_with(folder: Path, names=None) -> int:
    """Compare the current code with a snapshot (or the golden files): the accuracy tolerance.

    Prints, per case and pooled, the ok status changes and the normals' movements per estimator,
    and every bound of :data:`simtest.reconstruct.compare.ACCURACY` broken; returns 1 if any is.
    """
    from simtest.reconstruct.compare import compare_estimates, pooled_comparison

    cmps = []
    for name in names or sorted(cases()):
        with gzip.open(folder / f"{name}.json.gz", "rt", encoding="ascii") as fh:
            before = json.load(fh)
        c = compare_estimates(as_rows(before), as_rows(run_case(name)), name=name)
        cmps.append(c)
        moved = ", ".join(f"{k} median {v['median']:.2g} p95 {v['p95']:.2g} max {v['max']:.2g} deg"
                          for k, v in c.stats().items())
        print(f"{name}: {c.candidates} candidates, {len(c.status_changes)} ok status changes; {moved}")
    total = pooled_comparison(cmps)
    problems = total.problems()
    print(f"pooled: {total.candidates} candidates, {len(total.status_changes)} ok status changes; "
          + ("within the accuracy tolerance" if not problems else "; ".join(problems)))
    return 1 if problems else 0


def main(argv: list[str]) -> int:
    if argv[:1] == ["--renders"]:
        write_renders()
        return 0
    if argv[:1] == ["--snapshot"]:
        snapshot(Path(argv[1]), argv[2:])
        return 0
    if argv[:1] == ["--compare"]:
        return compare_with(Path(argv[1]), argv[2:])
    names = argv or sorted(cases())
    GOLDEN.mkdir(parents=True, exist_ok=True)
    for name in names:
        rows = run_case(name)
        write_golden(name, rows)
        n_ok = sum(r["status"] == "ok" for r in rows)
        print(f"{name}: {len(rows)} estimates, {n_ok} ok")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT.parent))
    raise SystemExit(main(sys.argv[1:]))
