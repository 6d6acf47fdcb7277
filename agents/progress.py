"""Progress bars that tell the truth: what ``train`` will really run and how fast, how far
``evaluate`` is.

SB3 runs whole rollouts, so ``--timesteps 3000`` with PPO's 2,048 steps per rollout trains 4,096
steps; the bar counts the steps that will really run, says so when the figure was rounded up, and
its rate is env steps per second of wall time (data collection and learning updates together).

The ETA follows that same rate (:class:`SteadyEta`): the remaining work divided by the whole run's
average speed so far. Rich's own ETA divides by the speed of the last 30 s, which for PPO swings
between a rollout's burst of steps and a learning update without any (an ETA that jumped between 10
minutes and 3 hours while the rate stayed steady), and for a slow plant between episodes.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator
from typing import Any

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    Task,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
)
from rich.text import Text


class SteadyEta(ProgressColumn):
    """ETA from the task's average speed since it started (done / elapsed), not from the last
    seconds' speed: steady through bursts of work and pauses (PPO's rollouts and updates)."""

    def render(self, task: Task) -> Text:
        eta = steady_eta_s(task.completed, task.total, task.elapsed)
        if eta is None:
            return Text("-:--:--", style="progress.remaining")
        minutes, seconds = divmod(math.ceil(eta), 60)
        hours, minutes = divmod(minutes, 60)
        return Text(f"{hours}:{minutes:02d}:{seconds:02d}", style="progress.remaining")


def steady_eta_s(done: float, total: float | None, elapsed_s: float | None) -> float | None:
    """Seconds left at the average speed so far; None before there is one (or without a total)."""
    if total is None or not elapsed_s or done <= 0:
        return None
    return max(total - done, 0.0) * elapsed_s / done


def rounded_timesteps(model: Any, timesteps: int) -> tuple[int, str]:
    """(the steps ``model.learn(timesteps)`` really runs, why) for SB3's whole rollouts."""
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

    n_envs = int(getattr(model, "n_envs", 1) or 1)
    if isinstance(model, OnPolicyAlgorithm):
        unit, what = model.n_steps * n_envs, f"rollouts of {model.n_steps:,} steps x {n_envs} envs"
    else:
        freq = getattr(model, "train_freq", None)
        steps = freq.frequency if freq is not None and str(freq.unit.value) == "step" else 1
        unit, what = steps * n_envs, f"collections of {steps:,} steps x {n_envs} envs"
    return math.ceil(timesteps / unit) * unit, f"whole {what}"


def announce(model: Any, timesteps: int, console: Console | None = None) -> int:
    """Say on ``console`` (stderr, where the bar draws) when SB3 will run more steps than asked;
    the steps it will run."""
    really, why = rounded_timesteps(model, timesteps)
    if really != timesteps:
        out = console or Console(stderr=True)
        out.print(
            f"training {really:,} steps: {timesteps:,} rounded up to {why}", highlight=False, soft_wrap=True
        )
    return really


def train_progress(total: int, console: Console | None = None) -> Any:
    """An SB3 callback drawing a bar over the ``total`` steps that will really run: done/total,
    env steps per second of wall time, elapsed, ETA (``.done``: the steps it saw)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class TrainProgress(BaseCallback):
        """A bar over the steps that will really run: done/total, env steps/s of wall time, elapsed, ETA."""

        def __init__(self, total: int, console: Console | None = None) -> None:
            super().__init__()
            self.total = total
            self.done = 0
            self._console = console or Console(stderr=True)
            self._bar: Progress | None = None
            self._task: TaskID | None = None
            self._start_steps = 0
            self._t0 = self._last = 0.0

        def _on_training_start(self) -> None:
            self._start_steps = int(self.model.num_timesteps)
            self._t0 = self._last = time.perf_counter()
            self._bar = Progress(
                TextColumn("train"),
                BarColumn(),
                TextColumn("{task.completed:,.0f}/{task.total:,.0f} steps"),
                TextColumn("{task.fields[rate]}"),
                TimeElapsedColumn(),
                TextColumn("ETA"),
                SteadyEta(),
                console=self._console,
            )
            self._bar.start()
            self._task = self._bar.add_task("train", total=self.total, rate="")

        def _update(self) -> None:
            assert self._bar is not None and self._task is not None
            self.done = int(self.model.num_timesteps) - self._start_steps
            wall = max(time.perf_counter() - self._t0, 1e-9)
            self._bar.update(self._task, completed=self.done, rate=f"{self.done / wall:,.0f} env-steps/s")

        def _on_step(self) -> bool:
            now = time.perf_counter()
            if now - self._last >= 0.2:
                self._last = now
                self._update()
            return True

        def _on_training_end(self) -> None:
            if self._bar is not None:
                self._update()
                self._bar.stop()

    return TrainProgress(total, console)


@contextlib.contextmanager
def episode_bar(console: Console | None = None) -> Iterator[Callable[[int, int], None]]:
    """A bar over evaluation episodes: done/total, elapsed, ETA; yields ``progress(done, total)``."""
    bar = Progress(
        TextColumn("evaluate"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("episodes"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        SteadyEta(),
        console=console or Console(stderr=True),
    )
    task = bar.add_task("evaluate", total=None)

    def progress(done: int, total: int) -> None:
        bar.update(task, completed=done, total=total)

    with bar:
        yield progress
