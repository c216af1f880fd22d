"""Training decreases the loss; checkpoints carry their config, resume, load; bad weights are DataErrors."""

from pathlib import Path

import numpy as np
import pytest
import torch

from ssf_common.errors import DataError
from ssf_flow_node.core.asf import checkpoint
from ssf_flow_node.core.asf.estimator import AsfFlowEstimator
from ssf_flow_node.core.asf.network import AsfConfig, AsfNet, MaskStrategy
from ssf_common.dataset.pairs import pair_files, read_pair
from ssf_flow_node.core.estimator import FlowConfig
from ssf_common.dataset.synthetic import synthetic_pair
from ssf_flow_node.core.training import TrainConfig, Trainer, TrainMode

TINY = AsfConfig(points=(256, 64, 32, 16), neighbours=(8, 8, 8, 4), encoder_width=8, level_widths=(8, 16, 16, 16),
                 cost_width=(8, 8, 8, 8), cost_neighbours=8, patch_neighbours=4, upconv_neighbours=4, flow_width=16)


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("pairs")
    for seed in range(2):
        pair = synthetic_pair(seed=seed, agents=2, points=1024)
        np.savez(folder / f"{seed:06d}.npz", pc1=pair.pc1, pc2=pair.pc2, flow=pair.flow, dynamic1=pair.dynamic1,
                 instance1=pair.instance1, pose1=np.eye(4), pose2=np.linalg.inv(pair.ego))
    return folder


def tiny_config(**changes) -> TrainConfig:
    values = dict(network=TINY, points=1024, batch_size=2, steps=40, learning_rate=1e-2, log_every=10,
                  checkpoint_every=1000, threads=1, ego_noise_m=0.0, ego_noise_deg=0.0)
    return TrainConfig(**{**values, **changes})


@pytest.mark.parametrize("mode, factor", [(TrainMode.SUPERVISED, 0.9), (TrainMode.SELF_SUPERVISED, 0.995)])
def test_tiny_training_run_decreases_the_loss(data, tmp_path, mode, factor):
    """(The Chamfer term has a floor from sampling, so the self-supervised loss falls by less.)"""
    torch.manual_seed(0)
    trainer = Trainer(tiny_config(mode=mode), pair_files(data), tmp_path / "tiny.pt", log=lambda line: None)
    fixed = trainer.batch()
    trainer.batch = lambda: fixed  # one batch over and over: the loss must go down
    result = trainer.run()
    assert result.step == 40 and len(result.losses) == 40
    assert np.mean(result.losses[-5:]) < factor * np.mean(result.losses[:5])


def test_weight_decay_does_not_erase_the_input_layer(data, tmp_path):
    """Weights that get little gradient must keep their size (Adam with an L2 term drove them to zero)."""
    torch.manual_seed(0)
    trainer = Trainer(tiny_config(steps=60, weight_decay=1e-2), pair_files(data), tmp_path / "tiny.pt", log=lambda line: None)
    first_layer = trainer.network.encoder[0].weight
    before = first_layer.detach().abs().mean().item()
    trainer.run()
    assert first_layer.detach().abs().mean().item() > 0.5 * before


def test_checkpoint_carries_config_and_resumes(data, tmp_path):
    out = tmp_path / "run.pt"
    Trainer(tiny_config(steps=3, network=TINY.model_copy(update={"strategy": MaskStrategy.IMPLICIT})),
            pair_files(data), out, log=lambda line: None).run()
    saved = checkpoint.load_asf_checkpoint(out)
    assert saved.config.strategy is MaskStrategy.IMPLICIT and saved.config.points == TINY.points
    assert saved.training["steps"] == 3 and saved.state["step"] == 3
    resumed = Trainer.resume(out, pair_files(data), out, steps=5, log=lambda line: None)
    assert resumed.step == 3 and resumed.config.network.strategy is MaskStrategy.IMPLICIT
    assert resumed.run().step == 5


def test_ctrl_c_stops_training_at_the_next_step_and_saves_it(data, tmp_path):
    import os
    import signal

    trainer = Trainer(tiny_config(steps=1000), pair_files(data), tmp_path / "stopped.pt", log=lambda line: None)
    original = trainer.batch
    calls = []

    def batch():
        calls.append(1)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGINT)
        return original()

    trainer.batch = batch
    assert trainer.run().step == 2
    assert checkpoint.load_asf_checkpoint(tmp_path / "stopped.pt").state["step"] == 2


def test_saved_weights_load_into_an_estimator(data, tmp_path):
    out = tmp_path / "weights.pt"
    checkpoint.save_asf_checkpoint(out, AsfNet(TINY), tiny_config().model_dump(mode="json"))
    config = FlowConfig()
    estimator = AsfFlowEstimator.load(out, config.preprocess, config.registration)
    pair = read_pair(pair_files(data)[0])
    result = estimator.estimate(pair.pc1, pair.pc2, pair.dynamic1)
    assert result.flow.shape == pair.pc1.shape and np.isfinite(result.flow).all()
    with pytest.raises(DataError, match="strategy"):
        AsfFlowEstimator.load(out, config.preprocess, config.registration, strategy="points")


def test_bad_weights_files_are_data_errors(tmp_path):
    with pytest.raises(DataError, match="no such weights file"):
        checkpoint.load_asf_checkpoint(tmp_path / "missing.pt")
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"\x00not a checkpoint" * 10)
    with pytest.raises(DataError, match="not a readable weights file"):
        checkpoint.load_asf_checkpoint(garbage)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(DataError, match="not an ssf asf checkpoint"):
        checkpoint.load_asf_checkpoint(foreign)
    mismatched = tmp_path / "mismatched.pt"
    checkpoint.save_asf_checkpoint(mismatched, AsfNet(TINY), {})
    payload = torch.load(mismatched, weights_only=True)
    payload["network"]["flow_width"] = 32
    torch.save(payload, mismatched)
    with pytest.raises(DataError, match="do not fit"):
        checkpoint.load_asf_checkpoint(mismatched)
