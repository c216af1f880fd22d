"""`ssf sim`, `ssf dataset export` and `ssf bench sim` from the command line."""

from __future__ import annotations

import json

from ssf_common.cli import main

SHORT = ["--set", "route.waypoints=[[0,0],[60,0]]", "--set", "ground.margin=30", "--set", "lidar.columns=256"]


def test_sim_runs_an_episode_and_writes_summary_and_picture(tmp_path, capsys):
    summary, picture = tmp_path / "episode.json", tmp_path / "episode.png"
    code = main(
        [
            "sim",
            "--scenario",
            "sparse_50",
            "--seed",
            "3",
            "--duration",
            "3",
            *SHORT,
            "--set",
            "agents.count=5",
            "--json",
            str(summary),
            "--render",
            str(picture),
        ]
    )
    assert code == 0
    result = json.loads(summary.read_text())
    assert result["seed"] == 3 and result["agents"] == 5 and result["outcome"] in {"running", "success", "collision"}
    assert result["time"] <= 3.0 + 1e-9 and result["distance"] > 1.0
    assert picture.stat().st_size > 10_000 and picture.read_bytes()[:4] == b"\x89PNG"
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1]) == result


def test_bad_input_is_one_line_and_exit_two(tmp_path, capsys):
    assert main(["sim", "--scenario", "nope"]) == 2
    assert main(["sim", "--scenario", "empty", "--set", "agents.count=-4"]) == 2
    assert main(["dataset", "export", "--scenario", "empty", "--frames", "0", "--out", str(tmp_path)]) == 2
    assert main(["bench", "sim", "--agents", "a,b"]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 4 and all(line.startswith("ssf: error: ") for line in errors)
    assert "agents.count" in errors[1]


def test_dataset_export_command(tmp_path):
    out = tmp_path / "data"
    assert (
        main(
            ["dataset", "export", "--scenario", "empty", "--frames", "1", "--out", str(out), "--points", "512", *SHORT]
        )
        == 0
    )
    assert (out / "pairs" / "000000.npz").is_file() and (out / "sequence" / "poses.txt").is_file()
    assert len(list((out / "sequence" / "velodyne").glob("*.bin"))) == 2
