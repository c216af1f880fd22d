"""Training the segmentation networks: a tiny run lowers the loss, checkpoints resume, the commands run end to end,
and the networks plug into the segmenter factory."""

from pathlib import Path

import numpy as np
import pytest
import torch

from ssf_bringup.cli import main
from ssf_common.dataset.estimates import flow_estimate_path, read_flow_estimate
from ssf_common.dataset.pairs import pair_files, write_pair
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_common.errors import DataError
from ssf_seg_node.core.base import SegInput
from ssf_seg_node.core.ogc import checkpoint
from ssf_seg_node.core.ogc.checkpoint import NetworkKind
from ssf_seg_node.core.ogc.network import OgcConfig
from ssf_seg_node.core.ogc.training import SegTrainConfig, SegTrainer, motion_scores
from ssf_seg_node.core.segmenter import SegConfig, make_segmenter

TINY = dict(input_width=8, widths=(16, 16, 32), embedding=16, decoder_width=16, heads=2, slots=4)
TINY_FLAGS = ["-p", "network.input_width:=8", "-p", "network.widths:=[16, 16, 32]", "-p", "network.embedding:=16",
              "-p", "network.decoder_width:=16", "-p", "network.heads:=2", "-p", "network.slots:=4", "-p", "points:=512"]


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("pairs")
    for seed in range(2):
        write_pair(folder / f"{seed:06d}.npz", synthetic_pair(seed=seed, agents=2, points=1024))
    return folder


def tiny_config(**changes) -> SegTrainConfig:
    values = dict(network=OgcConfig(**TINY), flow="gt", points=512, steps=30, learning_rate=3e-3, log_every=10,
                  checkpoint_every=1000, validate_every=1000, threads=1)
    return SegTrainConfig(**{**values, **changes})


@pytest.mark.parametrize("method", list(NetworkKind))
def test_tiny_training_run_lowers_the_loss(data, tmp_path, method):
    """(Without L_CD here: its sampling floor at 512 points would hide how far the other terms fall.)"""
    torch.manual_seed(0)
    trainer = SegTrainer(tiny_config(method=method, losses={"chamfer": 0.0}), pair_files(data), tmp_path / "tiny.pt",
                         log=lambda line: None)
    fixed = trainer.batch()
    trainer.batch = lambda: fixed  # one batch over and over: the loss must go down
    result = trainer.run()
    assert result.step == 30 and len(result.losses) == 30
    assert np.mean(result.losses[-5:]) < 0.8 * np.mean(result.losses[:5])


def test_checkpoints_carry_their_config_and_resume_with_validation_history(data, tmp_path):
    out = tmp_path / "run.pt"
    lines = []
    trainer = SegTrainer(tiny_config(steps=4, validate_every=2, validation_pairs=1), pair_files(data), out,
                         validation=pair_files(data), log=lines.append)
    trainer.run()
    assert any("validation: accuracy" in line for line in lines)
    saved = checkpoint.load_seg_checkpoint(out)
    assert saved.kind is NetworkKind.OGC and saved.state["step"] == 4 and len(saved.state["validation"]) == 2
    assert SegTrainConfig.model_validate(saved.training) == trainer.config
    resumed = SegTrainer.resume(out, pair_files(data), out, pair_files(data), steps=6, log=lambda line: None)
    assert resumed.step == 4 and len(resumed.history) == 2
    for name, value in resumed.network.state_dict().items():
        assert torch.equal(value, trainer.network.state_dict()[name]), name
    assert resumed.run().step == 6
    bare = tmp_path / "bare.pt"
    checkpoint.save_seg_checkpoint(bare, NetworkKind.OGC, trainer.network, trainer.config.model_dump(mode="json"))
    with pytest.raises(DataError, match="no optimizer state"):
        SegTrainer.resume(bare, pair_files(data), out)


def test_a_signal_stops_training_at_the_next_step_and_saves_it(data, tmp_path):
    """SIGTERM (a preempted job) or Ctrl-C: the step ends, the checkpoint is written, --resume continues from it."""
    import os
    import signal

    lines: list[str] = []
    trainer = SegTrainer(tiny_config(steps=1000), pair_files(data), tmp_path / "stopped.pt", log=lines.append)
    batches = {"count": 0}
    original = trainer.batch

    def batch():
        batches["count"] += 1
        if batches["count"] == 3:
            os.kill(os.getpid(), signal.SIGTERM)
        return original()

    trainer.batch = batch
    handler = signal.getsignal(signal.SIGTERM)
    assert trainer.run().step == 3
    assert checkpoint.load_seg_checkpoint(tmp_path / "stopped.pt").state["step"] == 3
    assert "stopped at step 3 by a signal" in lines[-1]
    assert signal.getsignal(signal.SIGTERM) is handler  # the job's handler is gone with the job


def test_training_reads_the_cached_flow_or_says_how_to_make_it(data, tmp_path):
    trainer = SegTrainer(tiny_config(flow="rigid"), pair_files(data), tmp_path / "x.pt", log=lambda line: None)
    with pytest.raises(DataError, match="ssf train seg-flow"):
        trainer.batch()


def test_commands_cache_the_flow_then_train_and_resume(data, tmp_path, capsys):
    """ssf train seg-flow writes NAME.flow_ego.npy beside each pair; ssf train seg trains on it and resumes."""
    assert main(["train", "seg-flow", "--data", str(data), "--estimator", "ego"]) == 0
    for path in pair_files(data):
        assert read_flow_estimate(path, "ego", 1024).shape == (1024, 3)
    assert flow_estimate_path(data / "000000.npz", "ego").name == "000000.flow_ego.npy"
    out = tmp_path / "seg.pt"
    argv = ["train", "seg", "--data", str(data), "--val", str(data), "--out", str(out), "--flow", "ego", "--steps", "2",
            "-p", "validate_every:=2", "-p", "validation_pairs:=1", *TINY_FLAGS]
    assert main(argv) == 0
    assert "validation: accuracy" in capsys.readouterr().err
    assert main(["train", "seg", "--data", str(data), "--out", str(out), "--resume", str(out), "--steps", "3"]) == 0
    assert checkpoint.load_seg_checkpoint(out).state["step"] == 3
    assert main(["train", "seg", "--data", str(data), "--out", str(tmp_path / "y.pt"), "--flow", "asf-none"]) == 2
    assert "ssf train seg-flow" in capsys.readouterr().err


def test_trained_networks_are_segmenters_built_by_name(data, tmp_path):
    torch.manual_seed(0)
    pair = synthetic_pair(seed=3, agents=2, points=1024)
    for method in NetworkKind:
        trainer = SegTrainer(tiny_config(method=method, steps=1), pair_files(data), tmp_path / f"{method.value}.pt",
                             log=lambda line: None)
        trainer.run()
        config = SegConfig(**{method.value: {"weights": str(trainer.out)}})
        result = make_segmenter(f"{method.value}-both", config).segment(pair.pc1, pair.flow)
        assert result.segmentation.dynamic_prob.shape == (1024,) and np.allclose(result.slots.sum(axis=1), 1.0, atol=1e-4)
        with pytest.raises(DataError, match="trained on input 'both', not 'flow'"):
            make_segmenter(f"{method.value}-flow", config)
    wrong_kind = SegConfig(ogc={"weights": str(tmp_path / "pointnet.pt")})
    with pytest.raises(DataError, match="holds a 'pointnet' network"):
        make_segmenter("ogc-both", wrong_kind)


def test_more_points_than_the_network_sees_take_their_neighbours_masks(data, tmp_path):
    trainer = SegTrainer(tiny_config(steps=1), pair_files(data), tmp_path / "n.pt", log=lambda line: None)
    trainer.run()
    pair = synthetic_pair(seed=4, agents=2, points=2048)
    config = SegConfig(ogc={"weights": str(trainer.out), "points": 512})
    result = make_segmenter("ogc-both", config).segment(pair.pc1, pair.flow)
    assert result.slots.shape[0] == 2048 and np.allclose(result.slots.sum(axis=1), 1.0, atol=1e-4)


def test_motion_scores_by_hand():
    scores = motion_scores(np.array([1, 1, 0, 0], bool), np.array([1, 0, 1, 0], bool))
    assert scores.accuracy == 0.5 and scores.moving_iou == pytest.approx(1 / 3)
    assert motion_scores(np.zeros(3, bool), np.zeros(3, bool)).moving_iou == 1.0
    assert SegInput("flow") is SegInput.FLOW
