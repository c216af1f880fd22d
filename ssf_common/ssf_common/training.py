"""What every network trainer shares: the step loop (until the step count, the time limit or a signal, with progress
lines and checkpoints) and resuming from a checkpoint's optimizer state."""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any

import numpy as np

from ssf_common.interrupts import stop_requests


class StepTrainer(ABC):
    """A network, its optimizer and step scheduler, trained step by step; subclasses give the loss of the next batch
    (`batch_loss`), write their checkpoint (`save`) and may add to the loop (`progress`, `clip_gradients`,
    `after_step`, `at_time_limit`). Their config holds steps, log_every, checkpoint_every, max_minutes, threads, seed."""

    config: Any
    network: Any
    optimizer: Any
    scheduler: Any
    log: Callable[[str], None]

    def __init__(self) -> None:
        self.step = 0
        self.rng = np.random.default_rng(self.config.seed)

    @abstractmethod
    def batch_loss(self) -> Any:
        """The training loss (a scalar tensor) of the next batch."""

    @abstractmethod
    def save(self) -> None:
        """Write the resumable checkpoint."""

    def progress(self, last: int) -> str:
        """More of the progress line, over the last `last` steps (e.g. an error the loss does not show)."""
        return ""

    def clip_gradients(self) -> None:
        """Bound the gradients before the optimizer's step (not by default)."""

    def after_step(self) -> None:
        """Work after each step (e.g. validation)."""

    def at_time_limit(self) -> None:
        """Work when the time limit ends the run early."""

    def restore(self, state: dict[str, Any], network_state: dict[str, Any]) -> None:
        """Continue from a checkpoint: its weights, optimizer, scheduler and step (the data order goes on afresh)."""
        self.network.load_state_dict(network_state)
        self.optimizer.load_state_dict(state["optimizer"])
        self.scheduler.load_state_dict(state["scheduler"])
        self.step = int(state["step"])
        self.rng = np.random.default_rng([self.config.seed, self.step])

    def optimizer_state(self) -> dict[str, Any]:
        """The optimizer's part of a resumable checkpoint."""
        return {"optimizer": self.optimizer.state_dict(), "scheduler": self.scheduler.state_dict(), "step": self.step}

    def run_steps(self) -> list[float]:
        """Train until `steps` or `max_minutes` or a signal, logging progress and saving checkpoints; the losses."""
        import torch

        config = self.config
        torch.set_num_threads(config.threads)
        self.network.train()
        started = time.monotonic()
        losses: list[float] = []
        with stop_requests() as stop:
            while self.step < config.steps:
                loss = self.batch_loss()
                self.optimizer.zero_grad()
                loss.backward()
                self.clip_gradients()
                self.optimizer.step()
                self.scheduler.step()
                self.step += 1
                losses.append(float(loss.detach()))
                elapsed = time.monotonic() - started
                if self.step % config.log_every == 0 or self.step == config.steps:
                    self.log(f"step {self.step}/{config.steps} loss {np.mean(losses[-config.log_every:]):.4f}"
                             f"{self.progress(config.log_every)} lr {self.scheduler.get_last_lr()[0]:.2e} "
                             f"elapsed {elapsed / 60:.1f} min")
                self.after_step()
                if self.step % config.checkpoint_every == 0:
                    self.save()
                if config.max_minutes and elapsed > config.max_minutes * 60:
                    self.log(f"time limit of {config.max_minutes} min reached at step {self.step}")
                    self.at_time_limit()
                    break
                if stop.is_set():
                    self.log(f"stopped at step {self.step} by a signal; saving (--resume continues)")
                    break
        self.save()
        self.network.eval()
        return losses
