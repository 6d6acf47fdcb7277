"""The main job: train PPO on the bundled cart-pole FMU, evaluate it against baselines, report.

``fmu-bridge demo`` runs it (in-process, no server): about half a minute of training on 2 cores,
a minute in all. It ends with a table and the paths of the run, the report, the MCAP recordings
and the Rerun file. The cart-pole's actions push -10 N or +10 N (there is no 0 N action), so the
fixed baselines are named by what they apply: ``constant:-10`` and ``constant:10``.
"""

from __future__ import annotations

import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from agents.evaluate import evaluate
from agents.report import summary, write
from agents.train import train
from bridge.experiment import load_experiment
from bridge.experiment.examples import example_experiment


def run_demo(
    *, console: Console, timesteps: int = 60_000, episodes: int = 20, out: Path | None = None
) -> Path:
    experiment = example_experiment("cartpole_balance")
    out = out or Path("runs") / f"demo-{time.strftime('%Y%m%d-%H%M%S')}"
    console.print(
        f"[bold]1/3[/bold] training PPO on the cart-pole FMU for {timesteps:,} steps ({experiment.name})"
    )
    result = train(experiment, overrides={"timesteps": timesteps, "eval_every": 10_000}, run_dir=out / "ppo")
    console.print(f"    {result.timesteps:,} steps in {result.wall_time_s:.0f} s")
    console.print(
        f"[bold]2/3[/bold] evaluating PPO, constant -10 N, constant +10 N and random pushes over "
        f"{episodes} seeded episodes each"
    )
    evaluation = evaluate(
        [str(result.run_dir), "constant:-10", "constant:10", "random"],
        experiment,
        episodes=episodes,
        workers=2,
        record_dir=Path("recordings") / out.name,
    )
    paths = write(
        evaluation,
        out / "evaluation",
        title="cart-pole FMU: PPO vs baselines",
        experiment=load_experiment(experiment),
    )
    table = Table("agent", "mean return", "episodes", "success rate", "ended by", title="evaluation")
    for row in summary(evaluation):
        table.add_row(
            row["agent"],
            f"{row['return']:.1f}",
            str(row["episodes"]),
            f"{row.get('success', float('nan')):.2f}",
            row["end"],
        )
    console.print(table)
    console.print("[bold]3/3[/bold] replay")
    rrd = _replay(evaluation.recordings, out / "evaluation" / "ppo.rrd", console)
    console.print(f"run directory:   {result.run_dir}\nreport:          {paths['report']}")
    for recording in evaluation.recordings:
        console.print(f"recording:       {recording}")
    if rrd is not None:
        console.print(f"Rerun recording: {rrd}  (view it with: rerun {rrd})")
    return out


def _replay(recordings: list[Path], target: Path, console: Console) -> Path | None:
    ppo = [p for p in recordings if p.name.startswith("ppo")]
    if not ppo:
        return None
    try:
        from bridge.recording.replay import replay
    except ImportError:
        console.print("    (replay is not available in this installation)")
        return None
    try:
        replay(ppo[0], save=target, episode=0)
    except Exception as exc:  # the demo's numbers stand without the viewer file
        console.print(f"    replay skipped: {exc}")
        return None
    return target
