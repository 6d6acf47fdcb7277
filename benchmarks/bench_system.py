"""Cost of a macro step of a system, in this process and across nodes, side by side in one run.

In this process: the DC motor and the gearbox load (two FMUs, two connections, Jacobi) against
a raw FMPy loop doing the same work (per macro step and component: setReal of the connected
input, doStep, getReal of the outputs). Target: at most 1.3x the raw loop.

Across nodes on loopback: N = 1..4 DC motors in a chain (``c_i.omega -> c_{i+1}.load_torque``),
each component in its own node process (``fmu-bridge system serve --component c_i``), Jacobi:
every node is sent its inputs before any answer is awaited, so they step in parallel. Against
one bare Zenoh round trip (the echo process of bench_remote.py, same payload as a node's
outputs frame). Target: a macro step of N components at most 2x one bare round trip.

    PYTHONPATH=$PWD python benchmarks/bench_system.py [--steps 20000] [--repeats 5]
        [--nodes 1,2,3,4] [--remote-steps 2000] [--no-distributed]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from benchmarks.common import RawFmpyLoop, fmt_us, interleaved, table
from bridge.experiment.config import parse_experiment
from bridge.models import example_fmu
from bridge.plant.system.plant import SystemPlant

H = 1e-3


def system_plant(directory: Path) -> SystemPlant:
    data = {
        "model": {"step_size": H, "episode_duration": 1e4},
        "system": {
            "components": {
                "motor": {"fmu": "example:dcmotor", "feedthrough": False, "parameters": {"voltage": 12.0}},
                "load": {"fmu": "example:gearload"},
            },
            "connections": ["motor.omega -> load.omega_in", "load.torque -> motor.load_torque"],
        },
        "actions": {"inputs": ["load.tau_ext"], "low": {"load.tau_ext": -1}, "high": {"load.tau_ext": 1}},
        "observations": {"outputs": ["load.omega"]},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    plant = SystemPlant(parse_experiment(data, source=directory / "bench.yaml"))
    plant.bind(["load.tau_ext"], ["load.omega"])
    plant.reset({}, [0.0])
    return plant


def raw_pair() -> tuple[RawFmpyLoop, RawFmpyLoop]:
    motor = RawFmpyLoop(
        example_fmu("dcmotor", "2.0", "cs"), ["load_torque"], ["omega"], H, start={"voltage": 12.0}
    )
    load = RawFmpyLoop(example_fmu("gearload", "2.0", "cs"), ["omega_in", "tau_ext"], ["torque", "omega"], H)
    return motor, load


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--nodes", default="1,2,3,4")
    parser.add_argument("--remote-steps", type=int, default=2000)
    parser.add_argument("--no-distributed", action="store_true")
    args = parser.parse_args()
    in_process(args)
    if not args.no_distributed:
        from benchmarks.bench_system_nodes import distributed

        distributed([int(n) for n in args.nodes.split(",")], args.remote_steps)


def in_process(args: argparse.Namespace) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        plant = system_plant(Path(tmp))
        motor, load = raw_pair()
        state = {"omega": 0.0, "torque": 0.0, "t": 0.0}

        def system(steps: int) -> None:
            for _ in range(steps):
                plant.step([0.0])

        def raw(steps: int) -> None:
            m, g = motor.fmu, load.fmu
            m_in, m_out, g_in, g_out = motor._in, motor._out, load._in, load._out
            omega, torque, t = state["omega"], state["torque"], state["t"]
            for _ in range(steps):
                m.setReal(m_in, [torque])
                g.setReal(g_in, [omega, 0.0])
                m.doStep(t, H)
                g.doStep(t, H)
                t += H
                omega = m.getReal(m_out)[0]
                torque, _ = g.getReal(g_out)
            state.update(omega=omega, torque=torque, t=t)

        rates = interleaved({"system": system, "raw": raw}, args.steps, args.repeats)
        plant.close()
        motor.close()
        load.close()
    ratio = rates["raw"] / rates["system"]
    rows = [
        ("raw FMPy loop (2 FMUs)", fmt_us(rates["raw"]), "1.00"),
        ("SystemPlant, Jacobi", fmt_us(rates["system"]), f"{ratio:.2f}"),
    ]
    print(table(rows, ("in-process macro step", "us/step", "x raw")))
    print(f"target <= 1.3x: {'met' if ratio <= 1.3 else 'NOT met'}")


if __name__ == "__main__":
    main()
