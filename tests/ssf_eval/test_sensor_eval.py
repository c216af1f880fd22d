"""Evaluation per sensor: --sensor and --sim-param reach the simulator and the result files; `ssf eval sensors` prints
and writes the per-sensor x per-scenario table."""

from __future__ import annotations

import json

import pytest
import yaml

from ssf_bringup.cli import main
from ssf_common.dataset.pairs import write_pair
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_common.errors import ConfigError
from ssf_eval.sensors.cli import seed_list


@pytest.fixture(scope="module")
def street(tmp_path_factory):
    """A short stress street (the junction, 70 m of road, 30 vehicles) as a scenario file."""
    path = tmp_path_factory.mktemp("scenario") / "short_junction.yaml"
    path.write_text(yaml.safe_dump({
        "description": "a short junction street for tests",
        "route": {"waypoints": [[0.0, 0.0], [70.0, 0.0]], "crosswalk_spacing": 1000.0},
        "ground": {"margin": 30.0},
        "agents": {"count": 30, "vehicle_fraction": 1.0, "keep_clear_of_start": 0.0},
        "ego": {"reference_speed": 0.0, "start_s": 35.0, "start_offset": -11.75, "start_heading": 90.0},
        "episode": {"warmup_s": 1.0},
    }))  # fmt: skip
    return str(path)


def test_eval_flow_runs_on_the_sensor_it_is_given(street, tmp_path, capsys):
    out = tmp_path / "flow.json"
    assert main(["eval", "flow", "--scenario", street, "--sensor", "vlp16", "--frames", "1", "--estimators", "zero",
                 "--protocol", "whole", "--json", str(out)]) == 0
    assert "vlp16 at 10 Hz" in capsys.readouterr().out
    document = json.loads(out.read_text())
    assert document["source"]["sensor"] == "vlp16" and document["source"]["overrides"] == {"lidar.model": "vlp16"}
    assert document["config"]["source"]["sensor"] == "vlp16"
    points = document["results"][0]["all"]["count"]
    assert 10_000 < points <= 16 * 1800  # a 16-beam sweep (the default 64-beam one returns ~60 k)


def test_eval_seg_follows_the_sensor_rate(street, tmp_path):
    out = tmp_path / "seg.json"
    assert main(["eval", "seg", "--scenario", street, "--sensor", "os1_128", "--sim-param", "lidar.rate_hz:=20",
                 "--frames", "1", "--methods", "geometric", "--points", "2048", "--json", str(out)]) == 0
    document = json.loads(out.read_text())
    assert document["source"]["sensor"] == "os1_128" and document["source"]["dt"] == pytest.approx(0.05)
    perception = document["config"]["perception"]
    assert perception["scan_period"] == pytest.approx(0.05)
    assert perception["seg"]["selection"]["scan_period"] == pytest.approx(0.05)
    assert perception["flow"]["rigid"]["scan_period"] == pytest.approx(0.05)


def test_sensor_overrides_need_the_simulator(tmp_path, capsys):
    write_pair(tmp_path / "pair_0000.npz", synthetic_pair(seed=0, agents=2, points=1024))
    assert main(["eval", "flow", "--data", str(tmp_path), "--sensor", "vlp16", "--estimators", "zero"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--sensor" in err[0] and "--scenario" in err[0]
    with pytest.raises(SystemExit) as refused:
        main(["eval", "flow", "--scenario", "empty", "--sensor", "vlp64", "--estimators", "zero"])
    assert refused.value.code == 2 and "invalid choice: 'vlp64'" in capsys.readouterr().err


def test_eval_sensors_prints_one_table_and_writes_every_cell(street, tmp_path, capsys):
    out = tmp_path / "sensors.json"
    assert main(["eval", "sensors", "--sensors", "vlp16,roof_2x32", "--scenarios", street, "--seeds", "7",
                 "--frames", "1", "--protocol", "paper", "--points", "2048", "--json", str(out)]) == 0
    table = capsys.readouterr().out
    rows = [line for line in table.splitlines() if line.startswith(("vlp16 ", "roof_2x32 "))]
    assert len(rows) == 2 and "targets" in table
    document = json.loads(out.read_text())
    cells = {cell["sensor"]: cell for cell in document["cells"]}
    assert set(cells) == {"vlp16", "roof_2x32"} and document["seeds"] == [7]
    for cell in cells.values():
        assert cell["pairs"] == 1 and cell["points_median"] == 2048 and cell["dynamic_points"] > 0
        assert set(cell["targets_met"]) == {"dynamic_epe", "ego_ratio", "moving_iou"}
        assert cell["ego"]["dynamic"]["epe3d"] > 0.1  # the cross traffic moves; ego motion alone misses it
        assert 0.0 <= cell["loop_seg"]["moving_iou"] <= 1.0
    assert document["config"]["sensors"] == ["vlp16", "roof_2x32"] and document["complete"] is True


def test_eval_sensors_refuses_a_seed_whose_traffic_does_not_fit_before_any_work(tmp_path, capsys):
    crowded = tmp_path / "crowded.yaml"
    crowded.write_text(yaml.safe_dump({"route": {"waypoints": [[0.0, 0.0], [60.0, 0.0]]}, "ground": {"margin": 30.0},
                                       "agents": {"count": 400, "vehicle_fraction": 1.0}}))
    out = tmp_path / "never.json"
    assert main(["eval", "sensors", "--scenarios", "stress_far", str(crowded), "--seeds", "0", "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "agents.count" in err[0] and not out.exists()


def test_seed_lists():
    assert seed_list("0-4") == [0, 1, 2, 3, 4] and seed_list("0-2,7") == [0, 1, 2, 7]
    for bad in ("a", "-1", "3-", "5-3"):
        with pytest.raises(ConfigError, match="--seeds"):
            seed_list(bad)


def test_a_car_overtaking_beside_a_32_beam_sensor_gets_its_motion():
    """stress_queue on a VLP-32C: a car slides past 3 m to the side, 0.4 m a scan faster than the crawling ego; the
    range-balanced sample keeps ~1 % of its flank, so only its ends tell its motion (rigid on whole scans, no mask)."""
    import numpy as np

    from sim_bridge.dataset.export import PROTOCOLS
    from ssf_common.config import build
    from ssf_eval.pipeline import PerceptionConfig
    from ssf_eval.sources import simulator_pairs
    from ssf_flow_node.core.estimator import WHOLE_SCAN, make_estimator

    rigid = make_estimator("rigid", build(PerceptionConfig, {"flow": WHOLE_SCAN}).flow)
    pairs = simulator_pairs("stress_queue", 10, 4, PROTOCOLS["whole"], None, {"lidar.model": "vlp32c"}).pairs
    for pair in pairs:
        car = pair.instance1 == 51
        ego_only = pair.flow[car] - (pair.pc1[car] @ pair.ego[:3, :3].T + pair.ego[:3, 3] - pair.pc1[car])
        assert car.sum() > 4000 and np.linalg.norm(ego_only.mean(axis=0)) > 0.35  # near, and overtaking
        error = np.linalg.norm(rigid.estimate(pair.pc1, pair.pc2).flow[car] - pair.flow[car], axis=1).mean()
        assert error < 0.1
