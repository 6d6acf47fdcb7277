"""Batched stepping, side by side in one run (medians of interleaved repeats).

Rates are per CPU second of this process (``time.process_time``), so they are per core and not
diluted by other load on the machine; PPO is in wall-clock timesteps/s.

Run: python benchmarks/bench_batch.py [--n 256] [--repeats 5] [--ppo-timesteps 8192] [--no-ppo]
     [--only raw|env|ppo|me ...]

1. Raw batch stepping on the trivial ``feedthrough`` FMU (FMI 2.0 CS, ``y = u``) and on ``typed``
   (every variable type, a counter and hooks): the native call alone and ``BatchPlant.step``
   (inputs in, outputs out), in instance-steps per second on one core.
2. The batch env (SB3 interface, Task included) at N envs vs SB3's ``DummyVecEnv`` over N
   ``FmuEnv``, and vs the same FMU's doStep-only loop in C over the same N instances, on the
   cart-pole (a balancing state feedback, so episodes run their 500 samples) and the DC motor
   (random voltages, 300-sample episodes with scenarios, uncertainty and sensor noise), and on
   the trivial FMU as an env (random inputs, 10,000-sample episodes). "doStep-only C /
   DummyVecEnv" is the bound on "batch / DummyVecEnv": no env can step faster than its FMU's own
   doStep calls, and the example FMUs integrate with 20 (cart-pole) and 100 (DC motor) RK4
   substeps per sample; the trivial FMU shows the env's own cost.
3. PPO timesteps/s on the batch env vs ``DummyVecEnv`` (8 envs, bench_train's hyperparameters,
   one torch thread).
4. Model exchange vs co-simulation per sample on the same model (``Model``: write inputs, advance,
   read outputs): the native fixed-step RK4 loop with as many substeps as the CS variant's own RK4
   (so both evaluate the equations equally often), and CVode; then the batch env at N envs over
   model exchange (the native batch loop, and the per-instance Python loop) vs co-simulation.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from common import table

from bridge.env.batch import BatchVecEnv
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.config import Experiment, load_experiment, parse_experiment
from bridge.experiment.examples import example_experiment
from bridge.fmu import Model
from bridge.models import example_fmu
from bridge.plant.batch import BatchPlant
from bridge.plant.experiment_model import experiment_plant_spec

RAW = {
    "feedthrough": ("u", "y"),
    "typed": ("real_in", "real_out"),
}  # model: (input, output)


def raw_experiment(model: str) -> str:
    u, y = RAW[model]
    return (
        f"model: {{fmu: 'example:{model}', step_size: 0.1, episode_duration: 1.0}}\n"
        f"actions: {{inputs: [{u}], low: {{{u}: -1}}, high: {{{u}: 1}}}}\n"
        f"observations: {{outputs: [{y}]}}\nreward: {{terms: [{{alive: 1.0}}]}}\n"
    )


GAINS = np.array([1.0, 1.5, 30.0, 5.0])  # a stabilising state feedback for the cart-pole


def interleaved(named: dict[str, Callable[[int], None]], steps: int, repeats: int) -> dict[str, float]:
    """Median steps per CPU second of each candidate (this process's CPU time, so a figure per
    core that other load on the machine does not dilute), measured in alternation."""
    for fn in named.values():
        fn(min(steps, 1000))
    rates: dict[str, list[float]] = {name: [] for name in named}
    for _ in range(repeats):
        for name, fn in named.items():
            start = time.process_time()
            fn(steps)
            rates[name].append(steps / max(time.process_time() - start, 1e-9))
    return {name: statistics.median(values) for name, values in rates.items()}


def raw_stepping(model: str, n: int, repeats: int) -> list[tuple[str, ...]]:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{model}.yaml"
        path.write_text(raw_experiment(model))
        plant = BatchPlant(experiment_plant_spec(load_experiment(path)), n, native=True)
    plant.bind([RAW[model][0]], [RAW[model][1]])
    for i in range(n):
        plant.reset(i, {}, [0.0])
    batch = plant.batch
    stepper, spec = batch._stepper, batch._spec
    assert stepper is not None and spec is not None
    inputs = np.random.default_rng(0).uniform(-1, 1, size=(n, 1))
    outputs, status, active = np.zeros((n, 1)), np.zeros(n, dtype=np.int32), np.ones(n, dtype=np.uint8)

    def native(samples: int) -> None:
        for _ in range(samples // n):
            stepper.step(
                spec, comps=batch._comps, active=active, inputs=inputs, outputs=outputs,
                k=batch.clock, status=status,
            )  # fmt: skip

    def plant_step(samples: int) -> None:
        for _ in range(samples // n):
            plant.step(inputs)

    def do_steps(samples: int) -> None:
        stepper.do_steps(spec, batch._comps, batch.clock, samples // n)

    rates = interleaved(
        {"native call": native, "BatchPlant.step": plant_step, "doStep only": do_steps}, n * 4000, repeats
    )
    plant.close()
    return [(f"{model}, N={n}: {name}", f"{rate / 1e6:.1f} M") for name, rate in rates.items()]


def cartpole_policy(obs: np.ndarray) -> np.ndarray:
    return (obs @ GAINS > 0).astype(np.int64)


def random_policy(rng: np.random.Generator, n: int) -> Callable[[np.ndarray], np.ndarray]:
    table_ = rng.uniform(-1, 1, size=(64, n, 1)).astype(np.float32)
    counter = iter(range(1 << 62))
    return lambda obs: table_[next(counter) % 64]


def env_loop(env: Any, policy: Callable[[np.ndarray], np.ndarray], n: int) -> Callable[[int], None]:
    state = {"obs": env.reset()}

    def run(samples: int) -> None:
        obs = state["obs"]
        for _ in range(samples // n):
            obs, _, _, _ = env.step(policy(obs))
        state["obs"] = obs

    return run


TRIVIAL_ENV = (
    "model: {fmu: 'example:feedthrough', step_size: 0.01, episode_duration: 100.0}\n"
    "actions: {inputs: [u], low: {u: -1}, high: {u: 1}}\n"
    "observations: {outputs: [y]}\nreward: {terms: [{alive: 1.0}]}\n"
)  # the trivial FMU as an env: 10,000-sample episodes, so the env's own cost is what is measured


def load_env_experiment(name: str) -> Experiment:
    if name != "feedthrough_env":
        return load_experiment(example_experiment(name))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{name}.yaml"
        path.write_text(TRIVIAL_ENV)
        return load_experiment(path)


def env_comparison(name: str, n: int, repeats: int) -> list[tuple[str, ...]]:
    from stable_baselines3.common.vec_env import DummyVecEnv

    exp = load_env_experiment(name)
    batch = BatchVecEnv(exp, n)
    dummy = DummyVecEnv([lambda: FmuEnv(exp) for _ in range(n)])
    for env in (batch, dummy):
        env.seed(0)
    rng = np.random.default_rng(0)
    policy = cartpole_policy if name.startswith("cartpole") else random_policy(rng, n)
    batch_loop, dummy_loop = env_loop(batch, policy, n), env_loop(dummy, policy, n)
    plant = batch.engine.plant.batch
    stepper, spec = plant._stepper, plant._spec
    assert stepper is not None and spec is not None
    k = plant.clock.copy()

    def floor(samples: int) -> None:
        stepper.do_steps(spec, plant._comps, k, samples // n)
        k[:] = 0  # stay inside the episode's time range

    rates = interleaved({"batch": batch_loop, "dummy": dummy_loop, "c": floor}, n * 300, repeats)
    batch.close()
    dummy.close()
    return [
        (f"{name}, N={n}: BatchVecEnv", f"{rates['batch'] / 1e3:.0f} k"),
        (f"{name}, N={n}: DummyVecEnv over FmuEnv", f"{rates['dummy'] / 1e3:.1f} k"),
        (f"{name}, N={n}: doStep-only loop in C", f"{rates['c'] / 1e3:.0f} k"),
        (f"{name}: batch / DummyVecEnv", f"{rates['batch'] / rates['dummy']:.1f}x"),
        (f"{name}: doStep-only C / DummyVecEnv (the bound)", f"{rates['c'] / rates['dummy']:.1f}x"),
        (f"{name}: doStep-only C / batch", f"{rates['c'] / rates['batch']:.2f}x"),
    ]


def ppo_comparison(timesteps: int, repeats: int) -> list[tuple[str, ...]]:
    import torch
    from bench_train import HYPERPARAMS
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    # One learner thread: on a shared machine torch's thread pool oversubscribes the cores (measured
    # at load 11 on 2 cores: 16 steps/s with the default pool, 650-700 with one thread).
    torch.set_num_threads(1)

    exp = load_experiment(example_experiment("cartpole_balance"))
    makers = {
        "BatchVecEnv": lambda: BatchVecEnv(exp, 8),
        "DummyVecEnv": lambda: DummyVecEnv([lambda: FmuEnv(exp) for _ in range(8)]),
    }
    rates: dict[str, list[float]] = {name: [] for name in makers}
    for _ in range(repeats):
        for name, make in makers.items():
            env = make()
            model = PPO("MlpPolicy", env, seed=0, device="cpu", **HYPERPARAMS)  # type: ignore[arg-type]
            start = time.perf_counter()
            model.learn(total_timesteps=timesteps)
            rates[name].append(timesteps / (time.perf_counter() - start))
            env.close()
    medians = {name: statistics.median(values) for name, values in rates.items()}
    ratio = medians["BatchVecEnv"] / medians["DummyVecEnv"]
    return [(f"PPO, cart-pole, 8 envs: {n}", f"{r:.0f}") for n, r in medians.items()] + [
        ("PPO: batch / DummyVecEnv", f"{ratio:.2f}x")
    ]


# model, inputs, outputs, FMU step, RK4 substeps of the CS variant (h / its solver_step)
ME_CASES = (
    ("cartpole", ["force"], ["x", "x_dot", "theta", "theta_dot"], 0.02, 20),
    ("dcmotor", ["voltage", "load_torque"], ["omega", "current"], 0.01, 100),
    ("bouncing_ball", [], ["h", "v"], 0.01, 1),
)


def model_loop(
    path: Path, inputs: list[str], outputs: list[str], h: float, **kw: Any
) -> Callable[[int], None]:
    model = Model(path, step_size_s=h, **kw)
    model.initialize()
    write = model.signals(inputs, writable=True).write if inputs else None
    read = model.signals(outputs).read
    u = [0.5] * len(inputs)

    def run(samples: int) -> None:
        model.reset()  # every run from t0: a few us against thousands of samples
        for _ in range(samples):
            if write is not None:
                write(u)
            model.advance(1)
            read()

    return run


def me_vs_cs(repeats: int) -> list[tuple[str, ...]]:
    rows: list[tuple[str, ...]] = []
    for name, inputs, outputs, h, substeps in ME_CASES:
        loops = {
            "CS": model_loop(example_fmu(name, "2.0", "cs"), inputs, outputs, h),
            "ME rk4": model_loop(
                example_fmu(name, "2.0", "me"), inputs, outputs, h, solver="rk4", solver_substeps=substeps
            ),
            "ME cvode": model_loop(example_fmu(name, "2.0", "me"), inputs, outputs, h),
        }
        rates = interleaved(loops, 2000, repeats)
        us = {key: 1e6 / rate for key, rate in rates.items()}
        rows += [(f"{name} (FMI 2.0), {key}", f"{value:.1f} us") for key, value in us.items()]
        rows.append((f"{name}: ME rk4 x{substeps} / CS", f"{us['ME rk4'] / us['CS']:.2f}x"))
    return rows


def me_batch_env(n: int, repeats: int) -> list[tuple[str, ...]]:
    """The batch env over model exchange (RK4 with the CS variant's substeps), the native batch
    loop and the per-instance Python loop, vs the same experiment in co-simulation."""
    import yaml

    rows: list[tuple[str, ...]] = []
    for name, substeps in (("cartpole_balance", 20), ("dcmotor_tracking", 100)):
        path = example_experiment(name)

        def variant(path: Path = path, **model: Any) -> Experiment:
            data = yaml.safe_load(path.read_text())
            data["model"].update(model)
            return parse_experiment(data, source=path)

        me = {"interface": "me", "solver": "rk4", "solver_substeps": substeps}
        envs = {
            "CS": BatchVecEnv(variant(), n),
            "ME, native batch loop": BatchVecEnv(variant(**me), n),
            "ME, Python loop over instances": BatchVecEnv(variant(**me), n, native=False),
        }
        for env in envs.values():
            env.seed(0)
        rng = np.random.default_rng(0)
        policy = cartpole_policy if name.startswith("cartpole") else random_policy(rng, n)
        rates = interleaved({key: env_loop(env, policy, n) for key, env in envs.items()}, n * 100, repeats)
        for env in envs.values():
            env.close()
        rows += [(f"{name}, N={n}, batch env: {key}", f"{rate / 1e3:.0f} k") for key, rate in rates.items()]
        rows += [(f"{name}: {key} / CS (cost)", f"{rates['CS'] / rates[key]:.2f}x") for key in list(envs)[1:]]
    return rows


SECTIONS = ("raw", "env", "ppo", "me")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--ppo-timesteps", type=int, default=8192)
    parser.add_argument("--no-ppo", action="store_true")
    parser.add_argument("--only", choices=SECTIONS, action="append", help="run only these sections")
    args = parser.parse_args()
    sections = set(args.only or SECTIONS) - ({"ppo"} if args.no_ppo else set())
    rows: list[tuple[str, ...]] = []
    header = ("what (median, one core)", "steps/s, us/sample or ratio")
    if "raw" in sections:
        rows += [row for model in RAW for row in raw_stepping(model, max(args.n, 1024), args.repeats)]
        if len(sections) > 1:  # progress: the other sections take minutes
            print(table(rows, header), flush=True)
    if "env" in sections:
        for name in ("cartpole_balance", "dcmotor_tracking", "feedthrough_env"):
            rows += env_comparison(name, args.n, args.repeats)
            if len(sections) > 1:
                print(table(rows[-6:], header), flush=True)
    if "ppo" in sections:
        rows += ppo_comparison(args.ppo_timesteps, max(1, args.repeats // 2))
    if "me" in sections:
        rows += me_vs_cs(args.repeats)
        rows += me_batch_env(args.n, args.repeats)
    print(table(rows, header))


if __name__ == "__main__":
    main()
