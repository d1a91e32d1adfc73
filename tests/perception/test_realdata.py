"""Perception on real captures from ../shared/realdata (never copied into the repo)."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import REALDATA

NEURA = REALDATA / "neura_smart_palletizer"
RCAN = REALDATA / "RCAN_scd_samples" / "back"


@pytest.mark.skipif(not NEURA.is_dir(), reason=f"real data not found at {NEURA} (see shared/realdata/README.md)")
def test_neura_pallet_rgbd_boxes_found_with_real_sizes():
    from perception.bench import bench_neura
    from perception.segment_depth import DepthEdgeSegmenter

    r = bench_neura(NEURA, DepthEdgeSegmenter())
    assert r["boxes"] >= 10
    # a camera looking down at a pallet ("a shelf on its back") is accepted and boxes are found.
    # Measured with the depth segmenter: recall 10/12 = 0.83, precision 0.56, size error
    # median 8.9 cm (docs/perception.md); the asserts leave one box of margin.
    assert r["recall"] >= 0.75, r
    assert r["precision"] >= 0.45, r
    assert r["size_err_median_m"] is not None and r["size_err_median_m"] < 0.12, r


@pytest.mark.skipif(not RCAN.is_dir(), reason=f"real data not found at {RCAN} (see shared/realdata/README.md)")
def test_rcan_polygons_parse_into_carton_masks():
    from perception.bench import labelme_masks

    masks = labelme_masks(RCAN / "anno" / "418.json", (4000, 4000))
    assert len(masks) >= 3 and all(m.any() for m in masks)
    assert all(m.dtype == bool for m in masks)


@pytest.mark.skipif(not RCAN.is_dir(), reason=f"real data not found at {RCAN} (see shared/realdata/README.md)")
def test_rcan_photo_cartons_found_without_depth():
    """One photo (484: five cartons): 4 found at IoU 0.5 when this was written."""
    from perception.bench import bench_rcan
    from perception.segment import load_segmenter

    r = bench_rcan(RCAN, load_segmenter(None, "auto"), progress=False, names=["484.jpg"])
    assert r["images"] == 1 and r["cartons"] == 5
    assert r["matched"] >= 3, r
    assert r["mean_iou_matched"] >= 0.6, r


@pytest.mark.slow
@pytest.mark.skipif(not RCAN.is_dir(), reason=f"real data not found at {RCAN} (see shared/realdata/README.md)")
def test_rcan_recall_over_all_photos():
    """All 11 photos, 151 cartons: recall 56/151 = 0.37, mean IoU 0.72 when this was written."""
    from perception.bench import bench_rcan
    from perception.segment import load_segmenter

    r = bench_rcan(RCAN, load_segmenter(None, "auto"), progress=False)
    assert r["cartons"] == 151
    assert r["recall"] >= 0.33, r
    assert r["mean_iou_matched"] >= 0.65, r
