"""FmuEnv.step vs the raw FMPy loop on the same FMU, in one run (medians of interleaved repeats).

Run: python benchmarks/bench_env.py [--experiment NAME] [--steps N] [--repeats R] [--isolated]
[--wall-clock]

Loops are timed in this thread's CPU time (both run wholly in this thread, so a busy machine
slows neither's figure); ``--wall-clock`` times them with the wall clock instead.

``--isolated`` adds the same env over ``IsolatedFmuPlant`` (the FMU in a child process behind a
deadline) to the interleaved loops, to state what isolation costs per step.

Then resets, timed one call at a time from outside (wall clock, medians): ``env.reset()`` after a
finished episode and back to back, on the FMI 2.0 co-simulation cart-pole (one input, four
outputs) with reset policy ``restore`` and no randomisation (every reset restores the snapshot
taken after initialisation). After an episode is the case training meets: the reset's code and
data are no longer in the caches the steps used, so what a reset touches counts, not only what
it computes. Target: <= 30 us, and no dearer than 1.5 times a raw FMPy loop's own
``fmi2SetFMUstate`` of its snapshot after an episode of the same length, timed side by side
(policies ``restore`` and ``auto``). Last, ``env.reset(seed=...)`` of the chosen experiment with its
per-episode randomisation (each reset initialises the FMU anew).

Both loops are driven by the same balancing controller, so episodes run their full 500 samples
and resets weigh the same in both. The env does everything an RL step needs (action mapping,
observation processing, reward, termination, info); the raw loop sets the input, steps and
reads the outputs with FMPy's API.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from common import RawFmpyLoop, fmt_us, interleaved, table

from bridge.env.fmu_env import FmuEnv
from bridge.experiment import load_experiment
from bridge.experiment.examples import example_experiment
from bridge.models import example_fmu
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.plant.isolated import IsolatedFmuPlant

OUTPUTS = ["x", "x_dot", "theta", "theta_dot"]
RESTORE_EXPERIMENT = """\
model: {fmu: 'example:cartpole', step_size: 0.02, sampling_time: 0.02, episode_duration: EPISODE_S,
        reset_policy: restore}
actions: {inputs: [force], low: {force: -10}, high: {force: 10}}
observations: {outputs: [x, x_dot, theta, theta_dot], scale: none}
reward: {terms: [{alive: 1.0}]}
"""
GAINS = (1.0, 1.5, 30.0, 5.0)  # a stabilising state feedback for the cart-pole


def push(y: list[float]) -> float:
    """Force in N from the unscaled state (positive force tips the pole towards -theta)."""
    return max(-10.0, min(10.0, sum(g * v for g, v in zip(GAINS, y))))


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument(
        "--experiment",
        default="cartpole_balance",
        help="cartpole_balance (discrete actions, raw observations) or cartpole_continuous "
        "(Box actions, scaled observations, sensor noise)",
    )
    parser.add_argument("--isolated", action="store_true", help="also measure the isolated plant")
    parser.add_argument(
        "--wall-clock", action="store_true", help="time with the wall clock instead of this thread's CPU time"
    )
    parser.add_argument("--reset-episodes", type=int, default=400, help="resets timed after episodes")
    parser.add_argument("--reset-samples", type=int, default=500, help="samples of those episodes")
    return parser.parse_args()


def main() -> None:
    args = parse_args()

    env = FmuEnv(example_experiment(args.experiment))
    discrete = env.action_space.shape == ()
    raw = RawFmpyLoop(example_fmu("cartpole", "2.0", "cs"), ["force"], OUTPUTS, 0.02, start={"theta0": 0.02})
    episode = env.task.sample_times().size - 1

    def env_loop(steps: int, env: FmuEnv = env) -> None:
        _, info = env.reset(seed=0)
        y = info["outputs"].tolist()
        for _ in range(steps):
            force = push(y)
            action = int(force > 0) if discrete else np.array([force / 10.0], dtype=np.float32)
            _, _, terminated, truncated, info = env.step(action)
            y = info["outputs"].tolist()
            if terminated or truncated:
                _, info = env.reset()
                y = info["outputs"].tolist()

    def raw_loop(steps: int) -> None:
        done = 0
        while done < steps:
            raw.reset()
            chunk = min(steps - done, episode)
            raw.run(chunk, action=lambda y: [10.0 if push(y) > 0 else -10.0] if discrete else [push(y)])
            done += chunk

    loops = {"raw FMPy loop": raw_loop, "FmuEnv.step": env_loop}
    if args.isolated:
        experiment = load_experiment(example_experiment(args.experiment))
        isolated = FmuEnv(experiment, plant=IsolatedFmuPlant(experiment_plant_spec(experiment)))
        loops["FmuEnv.step, isolated plant"] = lambda steps: env_loop(steps, isolated)
    # CPU time of this thread: both loops run wholly here, so waiting for a core on a busy machine
    # counts for neither; the isolated plant waits on its child process and needs the wall clock.
    wall = args.isolated or args.wall_clock
    rates = interleaved(loops, args.steps, args.repeats, time.perf_counter if wall else time.thread_time)
    ratio = rates["raw FMPy loop"] / rates["FmuEnv.step"]
    print(
        f"experiment: {args.experiment} (FMI 2.0 CS, 1 FMU step per sample, {episode}-sample episodes), "
        f"{args.steps} steps x {args.repeats} repeats, interleaved, "
        f"{'wall-clock' if wall else 'CPU'} time\n"
    )
    print(
        table(
            [(n, f"{r:,.0f}", fmt_us(r)) for n, r in rates.items()], ("loop", "steps/s (median)", "us/step")
        )
    )
    print(f"\ncost ratio FmuEnv / raw FMPy loop: {ratio:.3f}  (target <= 1.1)")
    if args.isolated:
        extra_us = (1 / rates["FmuEnv.step, isolated plant"] - 1 / rates["FmuEnv.step"]) * 1e6
        print(f"isolated plant: +{extra_us:.1f} us per step over the in-process plant")
        isolated.close()

    for policy in ("restore", "auto"):
        after, back_to_back, raw_us, whole_us, direct_us = reset_costs(
            args.reset_episodes, args.reset_samples, policy
        )
        print(
            f"env.reset() with reset policy {policy} (cart-pole FMI 2.0 CS, no randomisation), "
            f"{args.reset_episodes} resets of each kind: after a finished {args.reset_samples}-sample "
            f"episode {after:.1f} us (median; target <= 30 us), back to back {back_to_back:.1f} us; "
            f"after an episode, a raw FMPy loop's own state restore {raw_us:.1f} us: "
            f"ratio {after / raw_us:.2f} (target <= 1.5); its whole restart (restore, initial input, "
            f"first outputs as an observation) {whole_us:.1f} us: ratio {after / whole_us:.2f}; "
            f"the same with the FMU's functions called directly {direct_us:.1f} us: "
            f"ratio {after / direct_us:.2f}"
        )
    samples = []
    for _ in range(5):
        start = time.perf_counter()
        for i in range(2000):
            env.reset(seed=i)
        samples.append((time.perf_counter() - start) / 2000)
    print(
        "env.reset(seed=...) with per-episode randomisation: "
        f"{statistics.median(samples) * 1e6:.1f} us (median)"
    )
    env.close()
    raw.close()


def reset_costs(episodes: int, samples: int, policy: str = "restore") -> tuple[float, float, float, float]:
    """Median wall-clock us of ``env.reset()`` after a finished episode and right after a reset;
    of a raw FMPy loop's own state restore (``fmi2SetFMUstate`` of its snapshot after
    initialisation) after an episode of the same length; and of the raw loop's whole restart after
    an episode (:meth:`RawFmpyLoop.restart`: the restore, the initial input written, the first
    outputs read into an observation array: what ``env.reset()`` must do at the least), with
    FMPy's API and with the FMU's functions called directly (:meth:`RawFmpyLoop.restart_direct`),
    interleaved with the env's."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "restore.yaml"
        text = RESTORE_EXPERIMENT.replace("EPISODE_S", repr(samples * 0.02))
        path.write_text(text.replace("reset_policy: restore", f"reset_policy: {policy}"))
        env = FmuEnv(load_experiment(path))
    raw = RawFmpyLoop(example_fmu("cartpole", "2.0", "cs"), ["force"], OUTPUTS, 0.02)
    snapshot = raw.fmu.getFMUstate()
    action = np.zeros(1, dtype=np.float32)
    after, back_to_back, raw_after, raw_whole, raw_direct = [], [], [], [], []
    raw.prepare_direct()
    initial = [0.0]  # the force's start value: what env.reset() writes before its first observation
    env.reset(seed=0)
    clock = time.perf_counter
    for _ in range(episodes):
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
        start = clock()
        env.reset()
        after.append(clock() - start)
        start = clock()
        env.reset()
        back_to_back.append(clock() - start)
        raw.run(samples, action=lambda y: [0.0])
        start = clock()
        raw.fmu.setFMUstate(snapshot)
        raw.t = 0.0
        raw_after.append(clock() - start)
        raw.run(samples, action=lambda y: [0.0])
        start = clock()
        raw.restart(snapshot, initial)
        raw_whole.append(clock() - start)
        raw.run(samples, action=lambda y: [0.0])
        start = clock()
        raw.restart_direct(snapshot, initial)
        raw_direct.append(clock() - start)
    raw.fmu.freeFMUstate(snapshot)
    env.close()
    raw.close()
    us = [statistics.median(x) * 1e6 for x in (after, back_to_back, raw_after, raw_whole, raw_direct)]
    return us[0], us[1], us[2], us[3], us[4]


if __name__ == "__main__":
    main()
