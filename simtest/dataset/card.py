"""The ``dataset.json`` card (:func:`make_card`) and the README of a dataset folder (:func:`_readme`),
written by :func:`simtest.dataset.generate.generate`: deterministic, no times, hosts or worker counts.
"""

from __future__ import annotations

from simtest import __version__
from simtest.dataset.config import DatasetConfig
from simtest.dataset.sample import CHANNELS, mesh_sha256
from simtest.dataset.shards import CARD_NAME, FORMAT, FORMAT_VERSION, MANIFEST_NAME, SHARDS_DIR

__all__ = ["READING", "make_card"]


_CONVENTIONS = {
    "camera_frame": "OpenCV: x right, y down, z forward; origin at the camera centre",
    "pixels": "(u, v) = (column, row); pixel centres at integer coordinates",
    "K": "K = [[f, 0, M/2 - 0.5], [0, f, M/2 - 0.5], [0, 0, 1]] for an M x M image",
    "cam_to_world": "4 x 4: columns are the camera x, y, z axes and centre in the scene's world frame",
    "normals": "unit vectors in the camera frame facing the camera (n . ray < 0)",
    "lengths": "millimetres",
    "angles": "degrees in files (suffix _deg)",
    "curvature": "k1 >= k2, 1/mm, at the BP, from the renderer's ground truth",
    "isophotes": "tangent-plane model: circle of radius r_- (paper Prop. 2) about the foot of "
                 "the perpendicular from the camera to the tangent plane at the BP, imaged "
                 "exactly; t relative to the Phong peak; exact for planes with a co-located "
                 "light and cancelled falloff",
    "randomness": "sample i draws from numpy default_rng(SeedSequence([seed, i]))",
    "split": "sample i is in the first split whose cumulative fraction exceeds "
             "int(sha256('simtest-split:<seed>:<i>')[:8 bytes]) / 2^64",
}


READING = """\
import io, json, numpy as np
from PIL import Image
rows = [json.loads(l) for l in open("DIR/manifest.jsonl")]      # labels, one row per sample
row = rows[0]
z = np.load("DIR/shards/" + "shard-%05d.npz" % row["shard"])     # lazy, one entry per array
key = "%08d/" % row["index"]
image = np.asarray(Image.open(io.BytesIO(z[key + "sensor_png"].tobytes())))   # (H, W) uint8
normals = z[key + "normals"]                                      # (H, W, 3) float32
# or: import simtest.dataset; ds = simtest.dataset.open("DIR"); ds[0]["normals"]"""


def _readme(config: DatasetConfig, count: int) -> str:
    """A short README for people who receive the folder without simtest (deterministic)."""
    lines = [
        "# simtest dataset",
        "",
        f"{count} rendered samples (root seed {config.seed}) of specular highlights with exact labels,",
        "made by `simtest dataset generate`; `dataset.json` holds the config, conventions and units.",
        "",
        "## Files",
        "",
        "- `manifest.jsonl`: one JSON row per sample, in index order: family, every sampled",
        "  parameter, `K` (3 x 3), `cam_to_world` (4 x 4), `highlights` (BP pixel `bp_px` [u, v], BP",
        "  `bp_mm`, GT `normal` at the BP, curvatures `k1` >= `k2` in 1/mm, `isophotes`: the",
        "  tangent-plane isophote conic per isovalue), the shard file (`npz`) and each array's",
        "  sha256, dtype and shape.",
        "- `shards/shard-XXXXX.npz`: numpy archives (masks and specular image deflated) with one",
        "  entry `<index:08d>/<array>` per array; each row also has its `split` (train/val/test,",
        "  fixed by seed and index), `exposure_applied` (auto-exposure), `camera` (a camera file:",
        "  model, image size, light rig) and `labels_sha256` (hash of the row itself).",
        "",
        "## Arrays",
        "",
    ]
    for name, ch in CHANNELS.items():
        lines.append(f"- `{name}` ({ch['dtype']} {ch['shape']}, {ch['unit']}): {ch['description']}")
    lines += ["", "## Reading with numpy and PIL alone", "", "```python",
              READING.replace("DIR/", ""), "```", "",
              "Conventions: OpenCV camera frame (x right, y down, z forward), normals facing the camera,",
              "pixel centres at integer (u, v) = (column, row), lengths in mm, angles in degrees.", ""]
    return "\n".join(lines)


def make_card(config: DatasetConfig, *, status: str, counts: dict | None = None, variants: list | None = None) -> dict:
    """The ``dataset.json`` card (deterministic: no times, hosts or worker counts).

    Parameters
    ----------
    config : DatasetConfig
        The validated config of the dataset.
    status : str
        ``"incomplete"`` while shards are written, ``"complete"`` once the manifest is written.
    counts : dict, optional
        Final counts (e.g. ``{"samples": N, ...}``); empty while incomplete.
    variants : list of str, optional
        Mitsuba variants the samples were rendered with.

    Returns
    -------
    dict
        JSON-ready card: format and version, simtest version, seed, count, shard layout, canonical
        and as-given config with its fingerprint, sha256 of the bundled meshes used, the channel
        table (dtype, shape, unit) and the conventions (OpenCV camera frame, pixel (u, v) with
        integer pixel centres, mm, degrees).
    """
    cm = config.params.get("colon", {}).get("colon_mesh")  # the colon family's meshes: what it draws
    meshes = [*(() if cm is None else cm.args[:1] if cm.kind == "constant" else cm.args[0]), *{"liver"} & config.params.keys()]
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION, "simtest_version": __version__,
        "status": status, "seed": config.seed, "count": config.count, "shard_size": config.shard_size,
        "n_shards": config.n_shards, "isovalues": list(config.isovalues),
        "config_fingerprint": config.fingerprint(), "config": config.to_dict(),
        "config_as_given": config.raw, "counts": counts or {}, "variants": variants or [],
        "meshes": {f"meshes/{m}.ply": mesh_sha256(m) for m in meshes},
        "channels": CHANNELS,
        "image": ("per sample (record `color`): appearance \"phong\" gives one channel, the grey Phong "
                  "render (specular + diffuse) through the sensor model; appearance \"tissue\" gives "
                  "the virtual endoscope's RGB tissue render as an 8-bit sRGB video frame (3 channels)"),
        "splits": dict(config.splits),
        "auto_exposure": (None if config.auto_exposure is None else
                          {"percentile": config.auto_exposure[0], "level": config.auto_exposure[1],
                           "applied": "per sample, record field exposure_applied"}),
        "conventions": _CONVENTIONS,
        "layout": {
            "card": CARD_NAME,
            "manifest": MANIFEST_NAME + " (one JSON row per sample, in index order)",
            "shards": SHARDS_DIR + "/shard-XXXXX.npz, entries '<index:08d>/<array>' (.npy)",
            "shard_rows": SHARDS_DIR + "/shard-XXXXX.json",
            "hash": "sha256 of the array's C-order bytes",
        },
        "reading": READING,
    }
