"""Every `ssf` command against generated bad input: a non-zero exit, one stderr line, no traceback, no work done.

HOSTILE lists, per command, what a hostile user can hand it. The first test walks the real parser: a command
added without an entry here fails the suite the day it is added. Commands run in this process through
`ssf_bringup.cli.main`, so an escaping exception fails the test with its traceback.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bad_input.hostile import (
    KNOWN_BAD_YAML,
    SUITE,
    bad_overrides,
    bad_seeds,
    negative,
    not_positive,
    unwritable_paths,
)
from ssf_bringup.cli import build_parser, main
from ssf_common import scans

Case = Callable[[st.DrawFn, Path], list[str]]


def leaf_commands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()) -> set[str]:
    """'sim', 'bag info', ... : every command a user can run."""
    found: set[str] = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found |= leaf_commands(sub, (*prefix, name))
    return found or {" ".join(prefix)}


# What each command is handed. Every case must fail before any work starts.


def hostile_yaml_file(draw: st.DrawFn, folder: Path, name: str = "hostile.yaml") -> str:
    path = folder / name
    path.write_bytes(draw(st.one_of(
        st.sampled_from(KNOWN_BAD_YAML).map(str.encode),
        st.binary(min_size=1, max_size=300).filter(lambda raw: not _utf8(raw)),
    )))  # fmt: skip
    return str(path)


def _utf8(raw: bytes) -> bool:
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


def hostile_scan_file(draw: st.DrawFn, folder: Path) -> str:
    suffix = draw(st.sampled_from(scans.SUFFIXES))
    path = folder / f"scan{suffix}"
    xyz = np.full((8, 3), draw(st.sampled_from([np.nan, np.inf, 1e30, -1e30])), np.float32)
    content = {
        "random": draw(st.binary(max_size=600).filter(lambda raw: len(raw) % 16 or suffix != ".bin")),
        "far": xyz.tobytes(),
        "pcd as bin": b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\n",
    }[draw(st.sampled_from(["random", "far", "pcd as bin"]))]
    path.write_bytes(content)
    if suffix == ".bin" and content == xyz.tobytes():
        scans.write_bin(path, xyz)
    return str(path)


def bad_output(draw: st.DrawFn, folder: Path, folder_too: bool = True) -> str:
    """A file path no process can write (or, for outputs that must be files, an existing folder)."""
    return str(draw(st.sampled_from([p for p in unwritable_paths(folder) if folder_too or p != folder])))


def one_of(*cases: Case) -> Case:
    return lambda draw, folder: draw(st.sampled_from(cases))(draw, folder)


GRAPH = "nodes:\n  - executable: ssf_seg_node\n"


def graph_file(folder: Path) -> str:
    (folder / "graph.yaml").write_text(GRAPH)
    return str(folder / "graph.yaml")


def scan_pair(folder: Path) -> tuple[str, str]:
    xyz = np.random.default_rng(0).normal(scale=10.0, size=(64, 3)).astype(np.float32)
    np.save(folder / "t0.npy", xyz)
    np.save(folder / "t1.npy", xyz)
    return str(folder / "t0.npy"), str(folder / "t1.npy")


SIM = ["--scenario", "empty"]
HOSTILE: dict[str, Case] = {
    "sim": one_of(
        lambda d, f: ["sim", "--scenario", hostile_yaml_file(d, f)],
        lambda d, f: ["sim", *SIM, f"--seed={d(bad_seeds())}"],
        lambda d, f: ["sim", *SIM, f"--duration={d(not_positive())}"],
        lambda d, f: ["sim", *SIM, f"--rate={d(negative())}"],
        lambda d, f: ["sim", *SIM, *d(st.sampled_from([("-p",), ("--param",), ("--set",)])), d(bad_overrides())],
        lambda d, f: ["sim", *SIM, d(st.sampled_from(["--json", "--render"])), bad_output(d, f)],
    ),
    "dataset export": one_of(
        lambda d, f: ["dataset", "export", "--scenario", hostile_yaml_file(d, f), "--frames", "1", "--out", str(f / "o")],
        lambda d, f: ["dataset", "export", *SIM, "--frames", "1", "--out", str(f / "o"), "-p", d(bad_overrides())],
        lambda d, f: ["dataset", "export", *SIM, f"--frames={d(st.integers(max_value=0))}", "--out", str(f / "o")],
    ),
    "bench sim": one_of(
        lambda d, f: ["bench", "sim", "--agents=" + d(st.sampled_from(["a", "1,b", "-1", ",", "1.5"]))],
        lambda d, f: ["bench", "sim", "--agents", "0", f"--seed={d(bad_seeds())}"],
        lambda d, f: ["bench", "sim", "--agents", "0", f"--steps={d(st.integers(max_value=0))}"],
        lambda d, f: ["bench", "sim", "--agents", "0", "--json", bad_output(d, f)],
        lambda d, f: ["bench", "sim", "--scenario", hostile_yaml_file(d, f)],
        lambda d, f: ["bench", "sim", "--agents", "0", "-p", d(bad_overrides())],
    ),
    "launch": one_of(
        lambda d, f: ["launch", hostile_yaml_file(d, f)],
        lambda d, f: ["launch", graph_file(f), f"--duration={d(not_positive())}"],
        lambda d, f: ["launch", graph_file(f), "-p", d(bad_overrides())],
        lambda d, f: ["launch", str(f / "missing.yaml")],
        lambda d, f: ["launch", graph_file(f), f"--foxglove={d(bad_ports())}"],
    ),
    "demo": one_of(
        lambda d, f: ["demo", "--out", str(f / "o"), f"--duration={d(not_positive())}"],
        lambda d, f: ["demo", "--out", str(f / "o"), f"--seed={d(bad_seeds())}"],
        lambda d, f: ["demo", "--out", str(f / "o"), "--scenario", hostile_yaml_file(d, f)],
        lambda d, f: ["demo", "--out", bad_output(d, f, folder_too=False)],
        lambda d, f: ["demo", "--out", str(f / "o"), f"--foxglove={d(bad_ports())}"],
        lambda d, f: ["demo", "--out", str(f / "o"), "--video",
                      d(st.sampled_from([str(f / "v.avi"), str(f / "v"), "/proc/nope/v.gif"]))],
    ),
    "record": one_of(
        lambda d, f: ["record", f"--chunk-bytes={d(st.integers(max_value=1023))}"],
        lambda d, f: ["record", f"--chunk-seconds={d(not_positive())}"],
        lambda d, f: ["record", "-o", str(f / "bag"), d(st.sampled_from(["relative/topic", "chatter", "x"]))],
        lambda d, f: ["record", "-o", d(st.sampled_from([str(p) for p in unwritable_paths(f)]))],
    ),
    "bag info": lambda d, f: ["bag", "info", hostile_bag(d, f)],
    "bag play": one_of(
        lambda d, f: ["bag", "play", str(f / "no_bag"), f"--rate={d(not_positive())}"],
        lambda d, f: ["bag", "play", str(f / "no_bag"), f"--delay={d(negative())}"],
        lambda d, f: ["bag", "play", hostile_bag(d, f, readable=False)],
        lambda d, f: ["bag", "play", str(f / "no_bag"), f"--foxglove={d(bad_ports())}"],
    ),
    "view": one_of(
        lambda d, f: ["view", f"--port={d(bad_ports())}"],
        lambda d, f: ["view", "--port", "0", "--host", d(st.sampled_from(["", "no.such.host.invalid", "999.1.1.1"]))],
    ),
    "render": one_of(
        lambda d, f: ["render", hostile_bag(d, f), "--picture", str(f / "p.png")],
        lambda d, f: ["render", str(f / "no_bag"), "--picture", str(f / "p.png"), "-p", d(bad_overrides())],
        lambda d, f: ["render", str(f / "no_bag"), "--video", bad_output(d, f)],
        lambda d, f: ["render", str(f / "no_bag")],
    ),
    "bench view": one_of(
        lambda d, f: ["bench", "view", f"--rate={d(not_positive())}"],
        lambda d, f: ["bench", "view", f"--duration={d(not_positive())}"],
        lambda d, f: ["bench", "view", f"--points={d(st.integers(max_value=0))}"],
        lambda d, f: ["bench", "view", "--json", bad_output(d, f)],
    ),
    "bench transport": one_of(
        lambda d, f: ["bench", "transport", f"--rate={d(not_positive())}"],
        lambda d, f: ["bench", "transport", f"--duration={d(not_positive())}"],
        lambda d, f: ["bench", "transport", "--rate", "0.5", "--duration", "1"],
        lambda d, f: ["bench", "transport", "--json", bad_output(d, f)],
    ),
    "flow estimate": one_of(
        lambda d, f: ["flow", "estimate", hostile_scan_file(d, f), scan_pair(f)[1], "--out", str(f / "flow.npy")],
        lambda d, f: ["flow", "estimate", *scan_pair(f), "--flow-config", hostile_yaml_file(d, f),
                      "--out", str(f / "flow.npy")],
    ),
    "seg estimate": one_of(
        lambda d, f: ["seg", "estimate", *scan_pair(f), "--out", bad_output(d, f)],
        lambda d, f: ["seg", "estimate", *scan_pair(f), "--out", str(f / "seg.npy"), "--config", hostile_yaml_file(d, f)],
    ),
    "eval seg": lambda d, f: ["eval", "seg", "--scenario", "empty", "--config", hostile_yaml_file(d, f)],
    "eval fusion": one_of(
        lambda d, f: ["eval", "fusion", "--scenario", "empty", "--config", hostile_yaml_file(d, f)],
        lambda d, f: ["eval", "fusion", "--scenario", "empty", d(st.sampled_from(["--json", "--plot"])), bad_output(d, f)],
    ),
    "bench seg": lambda d, f: ["bench", "seg", "--config", hostile_yaml_file(d, f)],
    "bench fusion": lambda d, f: ["bench", "fusion", "--config", hostile_yaml_file(d, f)],
    "eval nav": one_of(
        lambda d, f: ["eval", "nav", "--agents=" + d(st.sampled_from(["a", "1,b", "-1", ",", "1.5"]))],
        lambda d, f: ["eval", "nav", "--perception", d(st.sampled_from(["lidar", "gt,,x", ",", "GT"]))],
        lambda d, f: ["eval", "nav", f"--trials={d(st.integers(max_value=0))}"],
        lambda d, f: ["eval", "nav", f"--seed={d(bad_seeds())}"],
        lambda d, f: ["eval", "nav", f"{d(st.sampled_from(['--route-length', '--time-limit']))}={d(not_positive())}"],
        lambda d, f: ["eval", "nav", f"--workers={d(st.integers(max_value=0))}"],
        lambda d, f: ["eval", "nav", f"--loop-iterations={d(st.one_of(st.integers(max_value=0), st.integers(min_value=21)))}"],
        lambda d, f: ["eval", "nav", "-p", d(bad_overrides())],
        lambda d, f: ["eval", "nav", d(st.sampled_from(["--json", "--plot", "--resume"])), bad_output(d, f)],
        lambda d, f: ["eval", "nav", f"--video-first={d(st.integers(max_value=-1))}"],
        lambda d, f: ["eval", "nav", "--video-first=1", "--video-dir", bad_output(d, f, folder_too=False)],
    ),
    "bench plan": one_of(
        lambda d, f: ["bench", "plan", "--obstacles=" + d(st.sampled_from(["a", "1,b", "-1", ",", "1.5", "100001"]))],
        lambda d, f: ["bench", "plan", f"--ticks={d(st.integers(max_value=0))}"],
        lambda d, f: ["bench", "plan", f"--seed={d(bad_seeds())}"],
        lambda d, f: ["bench", "plan", "--config", hostile_yaml_file(d, f)],
        lambda d, f: ["bench", "plan", "-p", d(bad_overrides())],
        lambda d, f: ["bench", "plan", "--json", bad_output(d, f)],
    ),
    "train flow": lambda d, f: ["train", "flow", "--data", str(f / "no_pairs"), "--out", str(f / "w.pt")],
    "train seg": one_of(
        lambda d, f: ["train", "seg", "--data", str(f / "no_pairs"), "--out", str(f / "w.pt")],
        lambda d, f: ["train", "seg", "--data", str(f), "--out", bad_output(d, f)],
        lambda d, f: ["train", "seg", "--data", str(f), "--out", str(f / "w.pt"), "-p", d(bad_overrides())],
    ),
    "train seg-flow": one_of(
        lambda d, f: ["train", "seg-flow", "--data", str(f / "no_pairs")],
        lambda d, f: ["train", "seg-flow", "--data", str(f), "--estimator", d(st.sampled_from(["nope", "", "rigid2"]))],
    ),
    "eval flow": lambda d, f: ["eval", "flow", "--scenario", hostile_yaml_file(d, f), "--frames", "1"],
    "odom run": one_of(
        lambda d, f: ["odom", "run", odom_folder(d, f), "--out", str(f / "o"), "--method", "points"],
        lambda d, f: ["odom", "run", odom_folder(d, f, hostile=False), "--out", bad_output(d, f)],
        lambda d, f: ["odom", "run", odom_folder(d, f, hostile=False), "--out", str(f / "o"),
                      "--config", hostile_yaml_file(d, f)],
        lambda d, f: ["odom", "run", odom_folder(d, f, hostile=False), "--out", str(f / "o"), "-p", d(bad_overrides())],
        lambda d, f: ["odom", "run", odom_folder(d, f, hostile=False), "--out", str(f / "o"),
                      f"--period={d(not_positive())}"],
        lambda d, f: ["odom", "run", hostile_bag(d, f), "--out", str(f / "o")],
    ),
    "eval odom": one_of(
        lambda d, f: ["eval", "odom", "--scenario", hostile_yaml_file(d, f), "--frames", "2"],
        lambda d, f: ["eval", "odom", "--scenario", "empty", f"--seed={d(bad_seeds())}"],
        lambda d, f: ["eval", "odom", "--scenario", "empty", "-p", d(bad_overrides())],
        lambda d, f: ["eval", "odom", "--scenario", "empty", d(st.sampled_from(["--json", "--plot"])), bad_output(d, f)],
    ),
    "bench odom": one_of(
        lambda d, f: ["bench", "odom", "--scenario", hostile_yaml_file(d, f), "--frames", "2"],
        lambda d, f: ["bench", "odom", "--scenario", "empty", "--json", bad_output(d, f)],
        lambda d, f: ["bench", "odom", "--scenario", "empty", "--odom-config", hostile_yaml_file(d, f)],
    ),
    "eval sensors": one_of(
        lambda d, f: ["eval", "sensors", "--seeds", d(st.sampled_from(["a", "-1", "5-3", "1.5", "", "0-99999"]))],
        lambda d, f: ["eval", "sensors", "--scenarios", hostile_yaml_file(d, f)],
        lambda d, f: ["eval", "sensors", "--sensors", d(st.sampled_from(["vlp64", "vlp16,x", "os1"]))],
        lambda d, f: ["eval", "sensors", "--sim-param", d(bad_overrides())],
        lambda d, f: ["eval", "sensors", "--config", hostile_yaml_file(d, f)],
        lambda d, f: ["eval", "sensors", "--json", bad_output(d, f)],
    ),
    "bench flow": lambda d, f: ["bench", "flow", "--scenario", hostile_yaml_file(d, f), "--frames", "1"],
    "bench graph": one_of(  # every case must fail before a process starts
        lambda d, f: ["bench", "graph", f"--duration={d(not_positive())}"],
        lambda d, f: ["bench", "graph", "--scenario", hostile_yaml_file(d, f)],
        lambda d, f: ["bench", "graph", "--json", bad_output(d, f)],
        lambda d, f: ["bench", "graph", f"--episodes={d(st.integers(max_value=-1))}"],
        lambda d, f: ["bench", "graph", "-p", d(st.sampled_from(["fusion.max_iterations:=1", "nobody:x:=1",
                                                                  "ssf_flow_node:=3", "ssf_flow_node:x:="]))],
    ),
    "bench faults": one_of(  # every case must fail before a process starts
        lambda d, f: ["bench", "faults", "--cases", d(st.sampled_from(["kill-radar-*", "nothing", "kill-flow-*,x"]))],
        lambda d, f: ["bench", "faults", "--scenario", hostile_yaml_file(d, f)],
        lambda d, f: ["bench", "faults", "--json", bad_output(d, f)],
        lambda d, f: ["bench", "faults", "--logs", str(d(st.sampled_from(unwritable_paths(f)[:2])))],
        lambda d, f: ["bench", "faults", "-p", d(st.sampled_from(["fusion.max_iterations:=1", "nobody:x:=1",
                                                                   "ssf_flow_node:=3", "ssf_flow_node:x:="]))],
    ),
}


def bad_ports() -> st.SearchStrategy[int]:
    """Port numbers no server can listen on."""
    return st.one_of(st.integers(max_value=-1), st.integers(min_value=65536))


def odom_folder(draw: st.DrawFn, folder: Path, hostile: bool = True) -> str:
    """A folder of two scans for `ssf odom run`: a good one, then a hostile one (or a second good one)."""
    scans_dir = folder / "scans"
    scans_dir.mkdir(exist_ok=True)
    for old in scans_dir.iterdir():
        old.unlink()
    np.save(scans_dir / "000.npy", np.random.default_rng(0).normal(scale=10.0, size=(64, 3)).astype(np.float32))
    second = hostile_scan_file(draw, folder) if hostile else None
    if second is None:
        np.save(scans_dir / "001.npy", np.random.default_rng(1).normal(scale=10.0, size=(64, 3)).astype(np.float32))
    else:
        Path(second).rename(scans_dir / ("001" + Path(second).suffix))
    return str(scans_dir)


def hostile_bag(draw: st.DrawFn, folder: Path, readable: bool = True) -> str:
    """Random bytes as a bag file; with `readable`, also after the right magic bytes (a damaged bag)."""
    path = folder / draw(st.sampled_from(["bag.mcap", "bag.db3"]))
    start = b"\x89MCAP0\r\n" if path.suffix == ".mcap" else b"SQLite format 3\x00"
    damaged = st.binary(max_size=400).map(lambda raw: start + raw)
    garbage = st.binary(max_size=400).filter(lambda raw: not raw.startswith(start[:4]))
    path.write_bytes(draw(st.one_of(garbage, damaged) if readable else garbage))
    return str(path)


def test_every_command_has_bad_input_cases():
    commands = leaf_commands(build_parser())
    missing = sorted(commands - set(HOSTILE))
    assert not missing, f"add bad-input cases for {missing} to HOSTILE in {__file__}"
    assert not set(HOSTILE) - commands, "HOSTILE names commands that no longer exist"


SLOW = {name: 8 for name in ("eval flow", "bench flow", "seg estimate", "eval seg", "eval fusion", "bench seg",
                              "bench fusion", "odom run", "eval odom", "bench odom", "eval sensors")}
# (commands that import torch and build estimators before they read input)


@pytest.mark.timeout(240)
@pytest.mark.parametrize("command", sorted(HOSTILE))
def test_every_command_answers_bad_input_in_one_line(tmp_path, capsys, command):
    @settings(SUITE, max_examples=min(SLOW.get(command, SUITE.max_examples), SUITE.max_examples))
    @given(data=st.data())
    def check(data: st.DataObject) -> None:
        argv = HOSTILE[command](data.draw, tmp_path)
        capsys.readouterr()
        code = main(argv)
        out, err = capsys.readouterr()
        lines = err.strip().splitlines()
        assert code != 0, f"{argv}: exit 0 on bad input"
        if code == 1 and command == "bag info":  # a readable but damaged bag: the table, then one warning
            assert len(lines) == 1 and lines[0].startswith("ssf: warning: "), err
        else:
            assert code == 2 and len(lines) == 1 and lines[0].startswith("ssf: error: "), f"{argv}: {err}"
            assert out == "", f"{argv} printed results: {out[:200]}"

    check()


@pytest.mark.parametrize(
    "argv",
    [
        ["sim", "--scenario", "empty", "--json", "/proc/nope/x.json"],
        ["sim", "--scenario", "empty", "--seed", "-7"],
        ["launch", "{graph}", "--duration", "-1"],
        ["bag", "play", "{bag}", "--delay", "inf"],
        ["sim", "--scenario", "{binary}"],
    ],
)
def test_as_a_process_bad_input_is_one_line_without_traceback(tmp_path, argv):
    (tmp_path / "binary.yaml").write_bytes(bytes(range(128, 256)))
    names = {"graph": graph_file(tmp_path), "bag": str(tmp_path / "no_bag"), "binary": str(tmp_path / "binary.yaml")}
    result = subprocess.run(
        [sys.executable, "-P", "-m", "ssf_bringup.cli", *[arg.format(**names) for arg in argv]],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr


SMALL_SCENARIO = (
    "agents: {count: 4}\nroute: {waypoints: [[0, 0], [60, 0]]}\nground: {margin: 30}\nlidar: {columns: 128, beams: 16}\n"
)
FLOW_CASES = [
    pytest.param(["flow", "estimate", "{t0}", "{t1}", "--mask", "{mask}", "--out", "{out}"], id="mask of strings"),
    pytest.param(["flow", "estimate", "{t0}", "{t1}", "-p", "preprocess.points=[1,", "--out", "{out}"], id="-p parse"),
    pytest.param(["flow", "estimate", "{t0}", "{t1}", "--out", "/proc/nope/flow.npy"], id="--out checked first"),
    pytest.param(["eval", "flow", "--scenario", "{small}", "--warmup", "0", "--frames", "0", "--estimators", "zero"],
                 id="--frames 0"),
    pytest.param(["eval", "flow", "--scenario", "{small}", "--warmup", "0", "--frames", "1", "--estimators", "zero",
                  "--json", "/proc/nope/x.json"], id="eval --json first"),
    pytest.param(["bench", "flow", "--scenario", "synthetic", "--frames", "1", "--estimators", "zero",
                  "--json", "/proc/nope/x.json"], id="bench --json late"),
]


@pytest.mark.parametrize("argv", FLOW_CASES)
def test_flow_commands_answer_bad_input_in_one_line_early(tmp_path, capsys, argv):
    t0, t1 = scan_pair(tmp_path)
    np.save(tmp_path / "mask.npy", np.array(["moving"] * 64))
    (tmp_path / "small.yaml").write_text(SMALL_SCENARIO)
    names = {"t0": t0, "t1": t1, "mask": str(tmp_path / "mask.npy"), "out": str(tmp_path / "flow.npy"),
             "small": str(tmp_path / "small.yaml")}
    assert main([arg.format(**names) for arg in argv]) == 2
    out, err = capsys.readouterr()
    assert len(err.strip().splitlines()) == 1 and out == ""
