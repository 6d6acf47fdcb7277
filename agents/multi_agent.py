"""Training several agents of one system together: independent PPO learners, taking turns.

The recipe (iterated best response with SB3's PPO): every agent has its own PPO model. In each
round, each agent in turn learns for ``timesteps`` samples while the others act with their
current policies (deterministically); its view of the system is a Gymnasium env
(:class:`AgentView`) over a PettingZoo env of its own (so a learner that stops mid-episode leaves
no other learner's episode half done). Returns are measured with every agent
deterministic over one episode, before training (the initial policies) and after each round, so
``improved`` compares an agent with its own untrained self on the same (deterministic) system.

    python -m agents.multi_agent examples/motor_load_agents.yaml --timesteps 2048 --rounds 2 [--record DIR]

prints each agent's untrained and trained return and exits non-zero if an agent did not improve.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium

from bridge.env.multi_agent import SystemParallelEnv

Policy = Callable[[Any], Any]


class AgentView(gymnasium.Env[Any, Any]):
    """One agent's Gymnasium env over the parallel env: the other agents act with ``policies``."""

    def __init__(self, env: SystemParallelEnv, agent: str, policies: Mapping[str, Policy]) -> None:
        self.env, self.agent, self.policies = env, agent, policies
        self.observation_space = env.observation_space(agent)
        self.action_space = env.action_space(agent)
        self._obs: dict[str, Any] = {}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        super().reset(seed=seed)
        self._obs, infos = self.env.reset(seed=seed, options=options)
        return self._obs[self.agent], infos[self.agent]

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        actions = {n: self.policies[n](self._obs[n]) for n in self.env.agents if n != self.agent}
        actions[self.agent] = action
        self._obs, rewards, terminated, truncated, infos = self.env.step(actions)
        a = self.agent
        return self._obs[a], rewards[a], terminated[a], truncated[a], infos[a]


def episode_returns(
    env: SystemParallelEnv, policies: Mapping[str, Policy], seed: int = 0
) -> dict[str, float]:
    """Each agent's return over one episode with every agent acting by ``policies``."""
    obs, _ = env.reset(seed=seed)
    totals = dict.fromkeys(env.possible_agents, 0.0)
    while env.agents:
        obs, rewards, *_ = env.step({n: policies[n](obs[n]) for n in env.agents})
        for n, r in rewards.items():
            totals[n] += r
    return totals


@dataclass
class TrainResult:
    """Returns per agent: before training and after each round."""

    untrained: dict[str, float]
    rounds: list[dict[str, float]] = field(default_factory=list)
    recording: Path | None = None  # the evaluation episodes, per agent (``record=``)

    @property
    def trained(self) -> dict[str, float]:
        return self.rounds[-1] if self.rounds else self.untrained

    def improved(self) -> dict[str, bool]:
        return {n: self.trained[n] > self.untrained[n] for n in self.untrained}


def train_agents(
    experiment: str | Path,
    *,
    timesteps: int = 2048,
    rounds: int = 2,
    seed: int = 0,
    save_dir: Path | None = None,
    record: Path | None = None,
) -> TrainResult:
    """Train every agent of ``experiment``'s ``system.agents`` with PPO, taking turns (module doc).

    ``record``: a folder; the evaluation episodes (untrained: episode 0, after round ``r``: episode
    ``r``) are recorded there per agent into one MCAP file (``fmu-bridge replay`` shows it)."""
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    env: Any = SystemParallelEnv(experiment)  # for the returns
    if record is not None:
        from bridge.recording.agents_recorder import record_agents

        env = record_agents(env, record, agent="independent PPO, taking turns", seed=seed)
    views: list[SystemParallelEnv] = []
    try:
        models: dict[str, Any] = {}
        policies: dict[str, Policy] = {}
        for i, name in enumerate(env.possible_agents):
            views.append(SystemParallelEnv(experiment))
            view = AgentView(views[-1], name, policies)
            models[name] = PPO(
                "MlpPolicy", view, n_steps=512, batch_size=64, learning_rate=1e-3, seed=seed + i, device="cpu"
            )
            policies[name] = _deterministic(models[name])
        result = TrainResult(untrained=episode_returns(env, policies, seed))
        if record is not None:
            result.recording = env.path
        for _ in range(rounds):
            for name in env.possible_agents:
                models[name].learn(total_timesteps=timesteps, reset_num_timesteps=False)
            result.rounds.append(episode_returns(env, policies, seed))
        if save_dir is not None:
            save_dir.mkdir(parents=True, exist_ok=True)
            for name, model in models.items():
                model.save(save_dir / f"{name}.zip")
        return result
    finally:
        for each in [env, *views]:
            each.close()


def _deterministic(model: Any) -> Policy:
    return lambda obs: model.predict(obs, deterministic=True)[0]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Train the agents of a system together (PPO, taking turns).")
    parser.add_argument("experiment", type=Path)
    parser.add_argument("--timesteps", type=int, default=2048, help="samples per agent per round")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--save-dir", type=Path, default=None, help="write each agent's PPO model here")
    parser.add_argument(
        "--record", type=Path, default=None, metavar="DIR",
        help="record the evaluation episodes per agent into DIR (fmu-bridge replay FILE shows them)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    result = train_agents(
        args.experiment,
        timesteps=args.timesteps,
        rounds=args.rounds,
        seed=args.seed,
        save_dir=args.save_dir,
        record=args.record,
    )
    print(f"{'agent':<12} {'untrained':>12} {'trained':>12}")
    for name, before in result.untrained.items():
        print(f"{name:<12} {before:>12.3f} {result.trained[name]:>12.3f}")
    if result.recording is not None:
        print(f"recording: {result.recording} (episode 0 untrained, episode r after round r)")
    return 0 if all(result.improved().values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
