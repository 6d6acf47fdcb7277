"""``fmu-bridge demo``: the main job on the embedded default, the bundled cart-pole FMU."""

from __future__ import annotations

from importlib.metadata import entry_points

import numpy as np
from rich.console import Console
from rich.table import Table

from bridge.env.fmu_env import FmuEnv
from bridge.experiment.examples import example_experiment

GAINS = np.array([1.0, 1.5, 30.0, 5.0])  # a stabilising state feedback for the cart-pole


def run_demo(*, console: Console, quick: bool = False) -> None:
    """The main job: with the ``train`` extra installed, train PPO, evaluate, report and record
    (``agents.train_demo``, found through the ``fmu_bridge.demo`` entry point); without it, or with
    ``quick``, balance the cart-pole with a state-feedback controller and print the trajectory."""
    if not quick:
        for entry in entry_points(group="fmu_bridge.demo"):
            try:
                full = entry.load()
            except ImportError:
                continue
            full(console=console)
            return
        console.print(
            "(training needs the train extra: pip install 'fmu-bridge[train]'; showing a controller)"
        )
    balance_with_controller(console)


def balance_with_controller(console: Console) -> None:
    with FmuEnv(example_experiment("cartpole_continuous")) as env:
        _, info = env.reset(seed=0)
        table = Table("t [s]", "x [m]", "theta [rad]", "force [N]", title="cart-pole FMU, state feedback")
        total = 0.0
        for step in range(500):
            force = float(np.clip(GAINS @ info["outputs"], -10.0, 10.0))
            _, reward, terminated, truncated, info = env.step(np.array([force / 10.0], dtype=np.float32))
            total += float(reward)
            if step % 50 == 0:
                x, _, theta, _ = info["outputs"]
                table.add_row(f"{info['time_s']:.2f}", f"{x:+.4f}", f"{theta:+.4f}", f"{force:+.3f}")
            if terminated or truncated:
                break
        console.print(table)
        console.print(f"episode return {total:.1f} over {info['step']} samples ({info['reason']})")
