"""The soak: real nodes, one killed and restarted under its name now and then, no spare; every
transition of every env checked against an in-process FmuEnv with the same seed.

``nodes`` real ``fmu-bridge node`` processes serve the continuous cart-pole on loopback; a
``RemoteVecEnv`` over them (``replace_dead``, no spare, so it waits for the same name to come
back) steps a constant action for ``seconds``. Every ``kill_every_s`` one node (in turn) is
killed with SIGKILL and started again under its name. Beside it, one in-process ``FmuEnv`` per env,
seeded as the vector env seeds its envs, takes the same steps: observations, rewards, dones and
terminal observations must be equal bit for bit. An env whose node died has its episode truncated
where it died (no step is taken there, in the reference either) and its next episode is drawn from
the same generator, so it stays comparable afterwards too.

Run the long form: ``python -m tests.net.soak --seconds 180`` (``tests/net/test_vec_heal.py``
runs a short one as a slow test).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bridge.env import RemoteVecEnv
from bridge.env.fmu_env import FmuEnv
from bridge.experiment.examples import example_experiment
from tests.conftest import Loopback, _wait_for_line, _wait_for_node, router_on_loopback, stop_process

CARTPOLE = example_experiment("cartpole_continuous")


@dataclass
class SoakReport:
    seconds: float = 0.0
    steps: int = 0  # vector steps
    transitions: int = 0  # env transitions compared with the reference
    episodes: int = 0  # episodes ended (terminated, truncated or cut by a dead node)
    kills: list[tuple[int, str]] = field(default_factory=list)  # (vector step, node killed)
    replaced: list[tuple[int, int, str, str]] = field(default_factory=list)  # (step, env, dead, new)
    mismatches: list[str] = field(default_factory=list)

    def summary(self) -> str:
        rate = self.transitions / self.seconds if self.seconds else 0.0
        return (
            f"{self.seconds:.0f} s, {self.steps:,} vector steps, {self.transitions:,} transitions "
            f"({rate:,.0f}/s), {self.episodes:,} episodes, {len(self.kills)} node(s) killed and "
            f"restarted, {len(self.replaced)} replacement(s), {len(self.mismatches)} mismatch(es)"
        )


def start_node(name: str, net: Loopback) -> subprocess.Popen[str]:
    args = ["node", str(CARTPOLE), "--name", name, "--connect", net.endpoint, "--prefix", net.prefix]
    return subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


class _Reference:
    """Env ``i``'s in-process twin: the same seed, the same steps, checked one by one."""

    def __init__(self, seed: int) -> None:
        self.env = FmuEnv(CARTPOLE)
        self.last, _ = self.env.reset(seed=seed)

    def check(
        self, report: SoakReport, where: str, action: np.ndarray, got: tuple[Any, Any, Any, dict[str, Any]]
    ) -> None:
        """One vector step's result for this env against the reference's own step."""
        obs, reward, done, info = got
        if "plant_error" in info:  # cut where its node died: no step here, a new episode
            expected_reward, expected_done, terminal = 0.0, True, self.last
            self.last, _ = self.env.reset()
        else:
            terminal, r, terminated, truncated, _ = self.env.step(action)
            expected_reward, expected_done = float(r), terminated or truncated
            self.last = terminal
            if expected_done:
                self.last, _ = self.env.reset()
        if expected_done != done or np.float32(expected_reward) != reward:
            report.mismatches.append(
                f"{where}: done/reward {done}/{reward}, expected {expected_done}/{expected_reward}"
            )
        if done:
            report.episodes += 1
            if not np.array_equal(np.asarray(info.get("terminal_observation")), terminal):
                report.mismatches.append(f"{where}: terminal observation {info.get('terminal_observation')}")
        if not np.array_equal(np.asarray(obs), self.last):
            report.mismatches.append(f"{where}: observation {obs}, expected {self.last}")
        report.transitions += 1


def soak(net: Loopback, *, seconds: float, kill_every_s: float, nodes: int = 4, seed: int = 11) -> SoakReport:
    """Step ``nodes`` real nodes for ``seconds``, killing one every ``kill_every_s`` (see above)."""
    names = [f"soak-{i}" for i in range(nodes)]
    processes = {name: start_node(name, net) for name in names}
    action = np.full((nodes, 1), 0.3, dtype=np.float32)
    report = SoakReport()
    vec = None
    try:
        for name, process in processes.items():
            _wait_for_line(process, "serving", timeout_s=120)
            _wait_for_node(net, name, timeout_s=30)
        vec = RemoteVecEnv(
            CARTPOLE,
            names,
            session=net.session,
            prefix=net.prefix,
            replace_dead=True,
            replace_wait_s=120.0,
            timeout_s=10.0,
        )
        vec.seed(seed)
        refs = [_Reference(seed + i) for i in range(nodes)]
        first = vec.reset()
        for i, ref in enumerate(refs):
            if not np.array_equal(first[i], ref.last):
                report.mismatches.append(f"reset, env {i}: observation {first[i]}, expected {ref.last}")
        started = time.monotonic()
        next_kill = started + kill_every_s
        while time.monotonic() - started < seconds:
            if time.monotonic() >= next_kill:
                victim = names[(2 + len(report.kills)) % nodes]
                processes[victim].send_signal(signal.SIGKILL)
                processes[victim].wait(timeout=10)
                stop_process(processes[victim], timeout_s=10)
                processes[victim] = start_node(victim, net)  # the vector env waits for it
                report.kills.append((report.steps, victim))
                next_kill += kill_every_s
            obs, rewards, dones, infos = vec.step(action)
            for i, ref in enumerate(refs):
                info = infos[i]
                if "node_replaced" in info:
                    moved = info["node_replaced"]
                    report.replaced.append((report.steps, i, moved["dead"], moved["new"]))
                got = (obs[i], rewards[i], dones[i], info)
                ref.check(report, f"vector step {report.steps}, env {i}", action[i], got)
            report.steps += 1
        report.seconds = time.monotonic() - started
        if vec.node_names != names:
            report.mismatches.append(f"the envs end on nodes {vec.node_names}, not {names}")
        for ref in refs:
            ref.env.close()
        return report
    finally:
        if vec is not None:
            vec.close()
        for process in processes.values():
            stop_process(process, timeout_s=10)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=180.0)
    parser.add_argument("--kill-every", type=float, default=30.0, help="seconds between two kills")
    parser.add_argument("--nodes", type=int, default=4)
    args = parser.parse_args()
    with router_on_loopback() as net:
        report = soak(net, seconds=args.seconds, kill_every_s=args.kill_every, nodes=args.nodes)
    print(report.summary())
    for k, victim in report.kills:
        print(f"  killed {victim} before vector step {k}")
    for k, i, dead, new in report.replaced:
        print(f"  vector step {k}: env {i} {dead} -> {new}")
    for line in report.mismatches[:20]:
        print(f"  MISMATCH {line}")
    sys.exit(1 if report.mismatches or len(report.replaced) != len(report.kills) else 0)


if __name__ == "__main__":
    main()
