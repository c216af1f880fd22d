"""The one step loop every trainer runs: step count, progress lines, checkpoints, validation hooks, resuming."""

from types import SimpleNamespace

import numpy as np
import torch

from ssf_common.training import StepTrainer


class LineTrainer(StepTrainer):
    """Fits y = 2x with one weight; records what the loop asks of it."""

    def __init__(self, **limits) -> None:
        self.config = SimpleNamespace(**{"steps": 6, "log_every": 2, "checkpoint_every": 3, "max_minutes": 0.0,
                                         "threads": 1, "seed": 0, **limits})
        self.network = torch.nn.Linear(1, 1, bias=False)
        self.optimizer = torch.optim.SGD(self.network.parameters(), lr=0.1)
        self.scheduler = torch.optim.lr_scheduler.StepLR(self.optimizer, step_size=100)
        self.lines, self.saved, self.events = [], [], []
        self.log = self.lines.append
        super().__init__()

    def batch_loss(self):
        x = torch.from_numpy(self.rng.normal(size=(8, 1)).astype(np.float32))
        return ((self.network(x) - 2.0 * x) ** 2).mean()

    def progress(self, last: int) -> str:
        return f" last {last}"

    def after_step(self) -> None:
        self.events.append(("after", self.step))

    def save(self) -> None:
        self.saved.append(self.step)


def test_the_loop_runs_every_step_logs_saves_and_lowers_the_loss():
    trainer = LineTrainer()
    losses = trainer.run_steps()
    assert trainer.step == 6 and len(losses) == 6 and losses[-1] < losses[0]
    assert trainer.saved == [3, 6, 6]  # every checkpoint_every steps, and at the end
    assert [line.split()[1] for line in trainer.lines] == ["2/6", "4/6", "6/6"]
    assert all(" last 2 lr " in line for line in trainer.lines)  # the subclass's part of the progress line
    assert trainer.events == [("after", step) for step in range(1, 7)]
    assert not trainer.network.training  # left in evaluation mode


def test_a_time_limit_ends_the_run_after_one_step_and_saves_it():
    trainer = LineTrainer(max_minutes=1e-9)
    called = []
    trainer.at_time_limit = lambda: called.append(trainer.step)
    trainer.run_steps()
    assert trainer.step == 1 and called == [1] and trainer.saved == [1]
    assert "time limit" in trainer.lines[-1]


def test_restore_takes_the_weights_optimizer_and_step_of_a_checkpoint():
    first = LineTrainer(steps=4)
    first.run_steps()
    second = LineTrainer(steps=6)
    second.restore(first.optimizer_state(), first.network.state_dict())
    assert second.step == 4
    assert torch.equal(second.network.weight, first.network.weight)
    second.run_steps()
    assert second.step == 6 and second.saved[-1] == 6
