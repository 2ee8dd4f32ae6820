"""``reconstruct`` returns a Reconstruction: the frame's estimates as a list, arrays and tables.

The tables are views of the same estimates: the Arrow table is the rows ``simtest reconstruct``
writes to ``estimates.parquet`` for a folder, the JSON the document it writes for one image.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from simtest.reconstruct import io, table
from simtest.reconstruct.pipeline import reconstruct
from simtest.reconstruct.result import NORMAL_COLUMNS, Reconstruction

REAL = Path(__file__).parent / "data" / "real"


@pytest.fixture(scope="module")
def tile():
    img = cv2.cvtColor(cv2.imread(str(REAL / "hyperkvasir_tile_r2c3_polyp.png")), cv2.COLOR_BGR2RGB)
    h, w = img.shape[:2]
    K = np.array([[140.0, 0, (w - 1) / 2], [0, 140.0, (h - 1) / 2], [0, 0, 1]])
    return img, K, reconstruct(img, K)


def test_the_arrays_are_the_estimates_columns(tile):
    img, K, rec = tile
    assert isinstance(rec, Reconstruction) and isinstance(rec, list)
    n = len(rec)
    assert n > 0 and rec.bp_px.shape == (n, 2) and rec.statuses.shape == (n,)
    for i, e in enumerate(rec):
        assert tuple(rec.bp_px[i]) == tuple(e.bp_px) and rec.statuses[i] == e.status
    normals = rec.normals()
    assert normals.shape == (n, len(NORMAL_COLUMNS), 3)
    j_rec, j_ray = NORMAL_COLUMNS.index("recommended"), NORMAL_COLUMNS.index("bp_ray")
    for i, e in enumerate(rec):
        np.testing.assert_array_equal(normals[i, j_rec], e.recommended.normal)
        np.testing.assert_array_equal(normals[i, j_ray], e.bp_ray)
        if e.cone_axis is None:
            assert np.isnan(normals[i, NORMAL_COLUMNS.index("cone_axis")]).all()
    # a rejected candidate carries no cone axis, an ok one does: both kinds are in this tile
    has_axis = ~np.isnan(normals[:, NORMAL_COLUMNS.index("cone_axis"), 0])
    assert has_axis[rec.ok].all() and not has_axis.all()
    with pytest.raises(ValueError, match="not a normal"):
        rec.normals(("cone_axis", "surface"))


def test_to_arrow_is_the_folder_table_and_to_json_the_image_document(tile, tmp_path):
    img, K, rec = tile
    t = rec.to_arrow(frame=3, source="tile.png")
    assert t.num_rows == len(rec)
    assert t.column("frame").to_pylist() == [3] * len(rec)
    want = table.estimates_batch(3, "tile.png", list(rec))
    assert t.equals(t.from_batches([want]))
    doc = json.loads(rec.to_json())
    written = io.estimates_document(list(rec), K=K, image_shape=img.shape,
                                    isovalues=rec.isovalues, normalise=rec.normalise,
                                    detection=rec.detection_record())
    assert doc == json.loads(io.dumps(written))
    assert doc["specularities"] == rec.rows()
    assert len(doc["specularities"]) == len(rec)


def test_an_empty_frame_gives_empty_tables():
    K = np.array([[100.0, 0, 59.5], [0, 100.0, 39.5], [0, 0, 1]])
    rec = reconstruct(np.zeros((80, 120, 3), np.uint8), K)
    assert len(rec) == 0 and rec.normals().shape == (0, len(NORMAL_COLUMNS), 3)
    assert rec.bp_px.shape == (0, 2) and rec.statuses.shape == (0,)
    assert rec.to_arrow().num_rows == 0
    assert json.loads(rec.to_json())["specularities"] == []
