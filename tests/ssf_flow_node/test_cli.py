"""The `ssf flow estimate` and `ssf train flow` commands end to end."""


import numpy as np
import pytest

from ssf_bringup.cli import main
from ssf_common.dataset.pairs import write_pair
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_flow_node.core.asf import checkpoint


@pytest.fixture(scope="module")
def pair():
    return synthetic_pair(seed=0, agents=2, points=4096)


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory, pair):
    folder = tmp_path_factory.mktemp("export")
    for index in range(2):
        write_pair(folder / f"pair_{index:04d}.npz", pair)
    return folder


def test_estimate_writes_flow_for_every_point(tmp_path, pair, capsys):
    np.save(tmp_path / "a.npy", np.column_stack([pair.pc1, np.ones(len(pair.pc1), np.float32)]))
    np.save(tmp_path / "b.npy", pair.pc2)
    np.save(tmp_path / "mask.npy", pair.dynamic1.astype(np.float32))
    out = tmp_path / "out" / "flow.npy"
    code = main(["flow", "estimate", str(tmp_path / "a.npy"), str(tmp_path / "b.npy"), "--mask", str(tmp_path / "mask.npy"),
                 "--estimator", "rigid", "--out", str(out), "-p", "preprocess.points=2048"])
    assert code == 0
    flow = np.load(out)
    assert flow.shape == (len(pair.pc1), 3) and flow.dtype == np.float32
    assert np.linalg.norm(flow - pair.flow, axis=1).mean() < 0.1
    assert "rigid" in capsys.readouterr().err


def test_estimate_reports_bad_inputs_in_one_line(tmp_path, pair, capsys):
    np.save(tmp_path / "a.npy", pair.pc1)
    (tmp_path / "broken.npy").write_bytes(b"garbage")
    args = ["flow", "estimate", str(tmp_path / "a.npy"), str(tmp_path / "broken.npy"), "--out", str(tmp_path / "f.npy")]
    assert main(args) == 2
    assert main(["flow", "estimate", str(tmp_path / "a.npy"), str(tmp_path / "a.npy"), "--mask", str(tmp_path / "a.npy"),
                 "--out", str(tmp_path / "f.npy")]) == 2
    assert main(["flow", "estimate", str(tmp_path / "a.npy"), str(tmp_path / "a.npy"), "-p", "preprocess.points=abc",
                 "--out", str(tmp_path / "f.npy")]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("ssf: error:")]
    assert len(errors) == 3
    assert "broken.npy" in errors[0] and "mask" in errors[1] and "preprocess.points" in errors[2]


def test_train_runs_and_resumes(export_dir, tmp_path):
    out = tmp_path / "tiny.pt"
    tiny = ["-p", "network.points:=[128,64,32,16]", "-p", "network.level_widths:=[8,16,16,16]",
            "-p", "network.cost_width:=[8,8,8,8]", "-p", "network.flow_width:=16", "-p", "points:=512"]
    assert main(["train", "flow", "--data", str(export_dir), "--out", str(out), "--steps", "2", "--batch-size", "1",
                 "--strategy", "points", *tiny]) == 0
    assert checkpoint.load_asf_checkpoint(out).state["step"] == 2
    first = {name: value.clone() for name, value in checkpoint.load_asf_checkpoint(out).network.state_dict().items()}
    assert main(["train", "flow", "--data", str(export_dir), "--out", str(out), "--resume", str(out), "--steps", "3"]) == 0
    resumed = checkpoint.load_asf_checkpoint(out)
    assert resumed.state["step"] == 3 and resumed.config.strategy.value == "points" and resumed.config.flow_width == 16
    assert any(not (value == first[name]).all() for name, value in resumed.network.state_dict().items())
    assert main(["flow", "estimate", str(export_dir / "pair_0000.npz"), str(export_dir / "pair_0000.npz"),
                 "--out", str(tmp_path / "x.npy")]) == 2  # .npz is not a scan format
