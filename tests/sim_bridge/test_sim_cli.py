"""`ssf sim`, `ssf dataset export` and `ssf bench sim` from the command line, and what they refuse."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from sim_bridge.node import SimBridgeNode
from sim_bridge.node import main as node_main
from sim_bridge.simulator import Simulator, episode_summary
from ssf_bringup.cli import main
from ssf_common.jsonio import write_json

SHORT = ["-p", "route.waypoints:=[[0,0],[60,0]]", "-p", "ground.margin=30", "--set", "lidar.columns=256"]
SMALL = ["route.waypoints=[[0,0],[60,0]]", "ground.margin=30", "lidar.columns=128", "agents.count=0"]


def strict_loads(text: str):
    return json.loads(text, parse_constant=lambda name: pytest.fail(f"non-standard JSON constant {name}"))


def test_sim_runs_an_episode_and_writes_summary_and_picture(tmp_path, capsys):
    summary, picture = tmp_path / "episode.json", tmp_path / "episode.png"
    code = main(
        [
            "sim", "--scenario", "sparse_50", "--seed", "3", "--duration", "3", *SHORT, "-p", "agents.count:=5",
            "--json", str(summary), "--render", str(picture),
        ]
    )  # fmt: skip
    assert code == 0
    result = strict_loads(summary.read_text())
    assert result["seed"] == 3 and result["agents"] == 5 and result["outcome"] in {"running", "success", "collision"}
    assert result["time"] <= 3.0 + 1e-9 and result["distance"] > 1.0
    assert picture.stat().st_size > 10_000 and picture.read_bytes()[:4] == b"\x89PNG"
    assert strict_loads(capsys.readouterr().out.strip().splitlines()[-1]) == result


def test_an_episode_without_steps_is_strict_json(tmp_path, small_scenario):
    sim = Simulator(small_scenario(agents=0), seed=1)
    sim.reset()
    summary = episode_summary(sim, 0.0)
    assert summary["min_clearance"] == math.inf  # nothing measured yet
    assert strict_loads(write_json(tmp_path / "episode.json", summary).read_text())["min_clearance"] is None


def bad_scenario_files(tmp_path):
    (tmp_path / "binary.yaml").write_bytes(bytes(range(128, 256)) * 8)
    (tmp_path / "alias.yaml").write_text("agents: &a {count: 10, x: *a}\n")
    (tmp_path / "deep.yaml").write_text("agents: " + "[" * 200 + "]" * 200 + "\n")
    return tmp_path


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--scenario", "nope"], "unknown scenario 'nope'"),
        (["--scenario", "empty", "-p", "agents.count=-4"], "agents.count"),
        (["--scenario", "empty", "--set", "agents.count=[1,"], "-p agents.count: not valid YAML"),  # --set is -p
        (["--scenario", "empty", "-p", "agents.count:="], "-p agents.count: the value is empty"),
        (["--scenario", "empty", "-p", "lidar.rolling_shutter:=sometimes"], "lidar.rolling_shutter"),
        (["--scenario", "empty", "-p", "route.waypoints:=[[0,0],[.nan,0]]"], "route.waypoints.1.0"),
        (["--scenario", "empty", "-p", "route.waypoints:=[[0,0],[1e30,0]]"], "more than 4000000"),
        (["--scenario", "empty", "--seed", "-7"], "--seed must be an integer from 0 to 4294967295, got -7"),
        (["--scenario", "empty", "--seed", "4294967296"], "--seed must be an integer"),
        (["--scenario", "empty", "--duration", "-5"], "--duration must be above 0, got -5"),
        (["--scenario", "empty", "--duration", "nan"], "--duration must be a finite number"),
        (["--scenario", "empty", "--rate", "-1"], "--rate must be at least 0"),
        (["--scenario", "empty", "--json", "/proc/nope/x.json"], "/proc/nope/x.json: cannot create the folder"),
        (["--scenario", "empty", "--offline", "--render", "/proc/nope/x.png"], "/proc/nope/x.png: cannot create"),
        (["--scenario", "{tmp}/binary.yaml"], "binary.yaml: not UTF-8 text (byte 0x80 at offset 0)"),
        (["--scenario", "{tmp}/alias.yaml"], "alias.yaml: refused at line 1, column 27: alias *a refers to a node"),
        (["--scenario", "{tmp}/deep.yaml"], "deep.yaml: refused at line 1"),
    ],
)
def test_bad_sim_input_is_one_line_and_exit_two_before_any_work(tmp_path, capsys, args, fragment):
    folder = bad_scenario_files(tmp_path)
    assert main(["sim", *[arg.format(tmp=folder) for arg in args]]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("ssf: error: ") and fragment in line


def test_bad_export_and_bench_input_is_one_line(tmp_path, capsys):
    assert main(["dataset", "export", "--scenario", "empty", "--frames", "0", "--out", str(tmp_path)]) == 2
    assert main(["dataset", "export", "--scenario", "empty", "--frames", "1", "--out", str(tmp_path),
                 "-p", "lidar.beams:=[1,"]) == 2  # fmt: skip
    assert main(["dataset", "export", "--scenario", "empty", "--frames", "1", "--out", str(tmp_path),
                 "--seed", "-7", *SHORT]) == 2  # fmt: skip
    assert main(["bench", "sim", "--agents", "a,b"]) == 2
    assert main(["bench", "sim", "--agents", "0", "--seed", "-1"]) == 2
    assert main(["bench", "sim", "--agents", "0", "--json", "/proc/nope/b.json"]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 6 and all(line.startswith("ssf: error: ") for line in errors)
    assert "-p lidar.beams: not valid YAML" in errors[1] and "seed must be an integer" in errors[2]


def test_the_node_refuses_an_unwritable_summary_and_a_negative_seed_at_once():
    base = ["--ros-args", "-p", "scenario:=empty", "-p", "exit_when_done:=false"]
    assert node_main([*base, "-p", "summary:=/proc/nope/x.json"]) == 2
    assert node_main([*base, "-p", "seed:=-7"]) == 2
    assert node_main([*base, "-p", "duration_s:=.nan"]) == 2


def test_sim_with_an_unwritable_summary_exits_at_once_in_node_mode(tmp_path):
    result = subprocess.run(
        [sys.executable, "-P", "-m", "ssf_bringup.cli", "sim", "--scenario", "empty", "--json", "/proc/nope/x.json"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines() == ["ssf: error: /proc/nope/x.json: cannot create the folder of the "
                                                  "--json summary (No such file or directory)"]


def test_a_summary_that_fails_at_the_end_still_ends_the_node_with_exit_one(tmp_path):
    out = tmp_path / "out"
    node = SimBridgeNode(argv=[
        "--ros-args", "-p", "scenario:=empty", "-p", f"overrides:={json.dumps(SMALL)}", "-p", "duration_s:=0.2",
        "-p", f"summary:={out / 'episode.json'}", "-p", "markers:=false",
    ])  # fmt: skip
    try:
        out.rmdir()  # made by the check at start; now a file stands where the folder was
        out.write_text("")
        for _ in range(10):
            node.tick()
        assert node.finished and node.shutdown_requested and node.exit_code == 1
    finally:
        node.destroy_node()


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
