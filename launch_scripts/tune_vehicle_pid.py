"""Tune the PID baseline of ``vehicle_path.yaml``: Nelder-Mead over (kp, ki, kd).

The objective is the mean IAE of the lateral error (m.s) over every training scenario with
seeds 1000.. (the held-out scenarios and the evaluation seeds 0.. are never seen), plus a
penalty of 100 m.s per episode that leaves the road. Gains are searched in log space from the
starting point given on the command line.

    python launch_scripts/tune_vehicle_pid.py --seeds 2 --iterations 120

prints the best gains; copy them into ``evaluation.baselines.pid`` of the experiment.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from agents.evaluate import run_episode
from agents.policies import Pid, PidSpec
from bridge.env import FmuEnv
from bridge.experiment import load_experiment

EXPERIMENT = Path(__file__).resolve().parents[1] / "examples" / "vehicle_path.yaml"


def objective(env: FmuEnv, base: dict[str, object], gains: np.ndarray, seeds: list[int]) -> float:
    kp, ki, kd = np.exp(gains)
    pid = Pid(PidSpec.model_validate({**base, "kp": kp, "ki": ki, "kd": kd}))
    total, count = 0.0, 0
    for scenario in env.task.experiment.schedule.training:
        for seed in seeds:
            trace = run_episode(env, pid, seed, scenario)
            error = trace.signals["lateral_ref"] - trace.signals["lateral_error"]
            dt = np.diff(trace.time_s)
            total += float(np.sum(np.abs(error[1:]) * dt)) + (100.0 if trace.terminated else 0.0)
            count += 1
    return total / count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2, help="episodes per training scenario")
    parser.add_argument("--iterations", type=int, default=120, help="Nelder-Mead iterations")
    parser.add_argument("--start", type=float, nargs=3, default=(0.1, 0.01, 0.05), help="kp ki kd")
    parser.add_argument(
        "--feedforward", nargs="*", default=None, metavar="SIGNAL:GAIN",
        help="feed-forward gains held fixed while tuning (default: the experiment's)",
    )  # fmt: skip
    args = parser.parse_args()
    experiment = load_experiment(EXPERIMENT)
    base = experiment.evaluation.baselines["pid"].settings()
    if args.feedforward is not None:
        base["feedforward_gains"] = {k: float(v) for k, _, v in (f.rpartition(":") for f in args.feedforward)}
    env = FmuEnv(experiment)
    seeds = [1000 + i for i in range(args.seeds)]
    x0 = np.log(np.asarray(args.start))
    print(f"start kp, ki, kd = {args.start}: IAE {objective(env, base, x0, seeds):.4f} m.s")
    result = minimize(
        lambda g: objective(env, base, g, seeds), x0, method="Nelder-Mead",
        options={"maxiter": args.iterations, "xatol": 1e-3, "fatol": 1e-4},
    )  # fmt: skip
    kp, ki, kd = np.exp(result.x)
    print(f"best kp = {kp:.4g} rad/m, ki = {ki:.4g} rad/(m.s), kd = {kd:.4g} rad.s/m: "
          f"mean IAE {result.fun:.4f} m.s over {result.nfev} evaluations")  # fmt: skip
    env.close()


if __name__ == "__main__":
    main()
