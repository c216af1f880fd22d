"""`ssf seg estimate`, `ssf eval seg`, `ssf eval fusion`, `ssf bench seg|fusion` end to end; the metrics by hand."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ssf_bringup.cli import main
from ssf_common.dataset.pairs import write_pair
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_common.records import Segmentation
from ssf_eval.seg.metrics import instance_counts, motion_counts, seg_scores, SegCounts


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pairs")
    for index in range(2):
        write_pair(folder / f"{index:06d}.npz", synthetic_pair(seed=index, agents=3, points=4096))
    return folder


def test_motion_and_instance_counts_by_hand():
    truth = np.array([0, 0, 1, 1, 1, 2, 2, 0])
    dynamic = truth > 0
    predicted = np.array([0, 1, 1, 1, 0, 0, 0, 0])
    assert motion_counts(predicted > 0, dynamic) == (2, 1, 3, 2)
    tp, fp, fn, iou = instance_counts(predicted, truth, dynamic, min_points=2)
    assert (tp, fp, fn) == (1, 0, 1) and iou == pytest.approx(2 / 4)  # object 1: 2 shared of 4 in the union
    scores = seg_scores(SegCounts(2, 1, 3, 2, 1, 0, 1, 0.5))
    assert scores.accuracy == pytest.approx(0.5) and scores.moving_iou == pytest.approx(2 / 6)
    assert scores.f1 == pytest.approx(2 / 3) and scores.pq == pytest.approx(0.5 / 1.5)
    # objects under min_points are ignored, and so are predictions lying on them
    assert instance_counts(np.array([1, 1, 0]), np.array([3, 3, 0]), np.array([True, True, False]), min_points=5)[:3] == (0, 0, 0)


def test_seg_estimate_writes_columns_and_obstacles(tmp_path, capsys):
    pair = synthetic_pair(seed=4, agents=3, points=8192)
    np.save(tmp_path / "a.npy", pair.pc1)
    np.save(tmp_path / "b.npy", pair.pc2)
    out, obstacles = tmp_path / "seg.npy", tmp_path / "obs.json"
    assert main(["seg", "estimate", str(tmp_path / "a.npy"), str(tmp_path / "b.npy"), "--out", str(out),
                 "--obstacles", str(obstacles), "-p", "flow.preprocess.remove_ground:=false"]) == 0
    columns = np.load(out)
    assert columns.shape == (len(pair.pc1), 6) and columns.dtype == np.float32
    label = columns[:, 1].astype(bool)
    assert ((columns[:, 0] > 0.5) == label).all() and (columns[label, 2] > 0).all() and (columns[~label, 2] == 0).all()
    assert (label == pair.dynamic1).mean() > 0.97
    found = json.loads(obstacles.read_text())["obstacles"]
    assert all(len(item["centre"]) == 3 and item["points"] > 0 for item in found)
    assert all(item["kind"] in ("vehicle", "pedestrian", "unknown") for item in found)
    moving = [item for item in found if item["moving"]]
    still = [item for item in found if not item["moving"]]
    assert 1 <= len(moving) <= 3 and all(item["id"] > 0 for item in moving)
    # the scene's walls and poles stand still beside the road: written too, with no velocity
    assert len(still) >= 4 and all(item["velocity"] == [0.0, 0.0, 0.0] for item in still)
    for item in still:  # none of them is a moving object written twice
        assert all(np.hypot(*np.subtract(item["centre"][:2], other["centre"][:2])) > 1.0 for other in moving)
    assert "moving and" in capsys.readouterr().err


def test_eval_seg_table_json_and_config(export_dir, tmp_path, capsys):
    out = tmp_path / "seg.json"
    assert main(["eval", "seg", "--data", str(export_dir), "--methods", "geometric", "ssf", "--flow", "gt",
                 "--json", str(out)]) == 0
    table = capsys.readouterr().out
    assert "geometric-both" in table and "ssf (rigid⇄geometric)" in table
    results = json.loads(out.read_text())
    rows = {row["method"]: row for row in results["results"]}
    assert rows["geometric-both"]["accuracy"] > 0.97 and rows["geometric-both"]["frames"] == 2
    assert results["config"]["perception"]["seg"]["method"] == "geometric"
    assert (tmp_path / "seg.config.yaml").is_file()


def test_eval_fusion_reports_every_iteration(export_dir, tmp_path, capsys):
    out, picture = tmp_path / "fusion.json", tmp_path / "fusion.png"
    assert main(["eval", "fusion", "--data", str(export_dir), "--iterations", "3", "--json", str(out),
                 "--plot", str(picture)]) == 0
    rows = json.loads(out.read_text())["iterations"]
    assert [row["iteration"] for row in rows] == [0, 1, 2]
    assert rows[-1]["converged_share"] >= rows[0]["converged_share"]
    assert picture.read_bytes()[:4] == b"\x89PNG"


def test_bad_method_and_frames_are_one_line(export_dir, capsys):
    assert main(["eval", "seg", "--data", str(export_dir), "--methods", "nothing"]) == 2
    assert main(["eval", "fusion", "--data", str(export_dir), "--frames", "0"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("ssf: error:")]
    assert len(errors) == 2 and "unknown segmenter" in errors[0] and "--frames" in errors[1]


def test_segmentation_static_helper():
    assert not Segmentation.static(4).dynamic.any()
