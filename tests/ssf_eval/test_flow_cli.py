"""`ssf eval flow` and `ssf bench flow` end to end, on exported and simulator pairs."""

import json

import pytest

from ssf_bringup.cli import main
from ssf_common.dataset.pairs import write_pair
from ssf_common.dataset.synthetic import synthetic_pair


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory):
    pair = synthetic_pair(seed=0, agents=2, points=4096)
    folder = tmp_path_factory.mktemp("export")
    for index in range(2):
        write_pair(folder / f"pair_{index:04d}.npz", pair)
    return folder


def test_eval_prints_table_and_writes_json(export_dir, tmp_path, capsys):
    out = tmp_path / "eval.json"
    code = main(["eval", "flow", "--data", str(export_dir), "--estimators", "zero", "ego", "rigid", "--json", str(out)])
    assert code == 0
    table = capsys.readouterr().out
    assert "dynamic" in table and "rigid" in table
    results = {entry["estimator"]: entry for entry in json.loads(out.read_text())["results"]}
    assert set(results) == {"zero", "ego", "rigid"}
    assert results["rigid"]["dynamic"]["epe3d"] < 0.5 * results["ego"]["dynamic"]["epe3d"]
    assert results["zero"]["all"]["count"] == 2 * 4096


def test_eval_rejects_missing_data(tmp_path, capsys):
    assert main(["eval", "flow", "--data", str(tmp_path / "nothing"), "--estimators", "zero"]) == 2
    assert "no such folder" in capsys.readouterr().err


def test_bench_reports_median_p95_and_rss(tmp_path):
    out = tmp_path / "bench.json"
    assert main(["bench", "flow", "--frames", "2", "--scenario", "synthetic", "--estimators", "zero", "ego",
                 "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert set(figures["estimators"]) == {"zero", "ego"}
    assert figures["estimators"]["ego"]["ms_p95"] >= figures["estimators"]["ego"]["ms_median"] > 0
    assert figures["peak_rss_mb"] > 0


def test_eval_on_simulator_pairs(capsys):
    assert main(["eval", "flow", "--scenario", "urban_100", "--frames", "2", "--estimators", "zero", "rigid"]) == 0
    table = capsys.readouterr().out
    assert "urban_100" in table and table.count("dynamic") == 2


def test_bench_on_whole_scans_runs_the_nodes_configuration(tmp_path):
    out = tmp_path / "bench.json"
    assert main(["bench", "flow", "--frames", "1", "--scenario", "synthetic", "--protocol", "whole", "--estimators",
                 "ego", "--json", str(out)]) == 0
    preprocess = json.loads(out.read_text())["config"]["flow"]["preprocess"]
    assert preprocess["remove_ground"] and preprocess["points_share"] > 0  # the flow node's whole-scan defaults
