"""Cost of a macro step of a system, in this process and across nodes, side by side in one run.

In this process: the DC motor and the gearbox load (two FMUs, two connections, Jacobi): the
native master (one native call per macro step), the Python master (over each component's
native sample), the same system written as an SSP whose speed connection converts rad/s to rpm
(``ssd:Units``) and whose torque passes a ``LinearTransformation`` (native and Python master),
a raw FMPy loop doing the same work (per macro step and component: setReal of
the connected input, doStep, getReal of the outputs), and Ecos's own C++ loop (``ecospy``) on
the same two FMUs and connections, called once per macro step and once for all of them. Target:
at most 1.3x the raw loop; the native master no slower than Ecos's loop; with transformations and
units, the native master within 1.2x of the plain one and no slower than Ecos's plain ``step(1)``. Ecos needs
``libtbb.so.12`` (Debian: ``apt-get install libtbb12``); without it that row says why.

Across nodes on loopback: N = 1..4 DC motors in a chain (``c_i.omega -> c_{i+1}.load_torque``),
each component in its own node process (``fmu-bridge system serve --component c_i``), Jacobi:
every node is sent its inputs before any answer is awaited, so they step in parallel. Against
one bare Zenoh round trip (the echo process of bench_remote.py, same payload as a node's
outputs frame). Target: a macro step of N components at most 2x one bare round trip.

    PYTHONPATH=$PWD python benchmarks/bench_system.py [--steps 20000] [--repeats 5]
        [--nodes 1,2,3,4] [--remote-steps 2000] [--no-distributed] [--cpu-time]

``--cpu-time`` times the in-process candidates by this thread's CPU time instead of the wall clock:
on a shared machine the time spent waiting for a core then weighs on none of them.

Typed links: 2 and 12 typed FMUs (FMI 2.0) in a chain passing Real, Integer, Boolean and
Enumeration values, on the native master and on the Python master (the ratio the second table
prints is the Python master's cost over the native master's, per macro step). Every in-process
candidate runs wholly in this thread (Ecos's loop included: it starts no worker thread for this
system), so the comparison stays fair.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

from benchmarks.common import RawFmpyLoop, fmt_us, interleaved, table
from bridge.experiment.config import parse_experiment
from bridge.models import example_fmu
from bridge.plant.system.plant import SystemPlant

H = 1e-3


_SSD = """<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription version="1.0" name="bench"
    xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon">
  <ssd:System name="bench">
    <ssd:Elements>
      <ssd:Component name="motor" source="resources/dcmotor.fmu"><ssd:Connectors>
        <ssd:Connector name="load_torque" kind="input"><ssc:Real/></ssd:Connector>
        <ssd:Connector name="omega" kind="output"><ssc:Real unit="rad/s"/></ssd:Connector>
      </ssd:Connectors></ssd:Component>
      <ssd:Component name="load" source="resources/gearload.fmu"><ssd:Connectors>
        <ssd:Connector name="omega_in" kind="input"><ssc:Real unit="rpm"/></ssd:Connector>
        <ssd:Connector name="torque" kind="output"><ssc:Real/></ssd:Connector>
      </ssd:Connectors></ssd:Component>
    </ssd:Elements>
    <ssd:Connections>
      <ssd:Connection startElement="motor" startConnector="omega" endElement="load" endConnector="omega_in"/>
      <ssd:Connection startElement="load" startConnector="torque"
          endElement="motor" endConnector="load_torque">
        <ssc:LinearTransformation factor="0.5" offset="0.01"/>
      </ssd:Connection>
    </ssd:Connections>
  </ssd:System>
  <ssd:Units>
    <ssc:Unit name="rad/s"><ssc:BaseUnit rad="1" s="-1"/></ssc:Unit>
    <ssc:Unit name="rpm"><ssc:BaseUnit rad="1" s="-1" factor="0.10471975511965977"/></ssc:Unit>
  </ssd:Units>
</ssd:SystemStructureDescription>
"""


def transformed_ssp(directory: Path) -> Path:
    """The motor and load as an SSP: rad/s -> rpm on the speed, 0.5 x + 0.01 on the torque."""
    path = directory / "transformed.ssp"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("SystemStructure.ssd", _SSD)
        archive.write(example_fmu("dcmotor", "2.0", "cs"), "resources/dcmotor.fmu")
        archive.write(example_fmu("gearload", "2.0", "cs"), "resources/gearload.fmu")
    return path


def system_plant(
    directory: Path, *, native: bool = True, sample: int = 1, transformed: bool = False
) -> SystemPlant:
    motor: dict[str, object] = {"feedthrough": False, "parameters": {"voltage": 12.0}}
    system: dict[str, object] = {
        "components": {"motor": {"fmu": "example:dcmotor", **motor}, "load": {"fmu": "example:gearload"}},
        "connections": ["motor.omega -> load.omega_in", "load.torque -> motor.load_torque"],
    }
    if transformed:
        system = {"components": {"motor": motor}}
    data = {
        "model": {
            "step_size": H,
            "sampling_time": sample * H,
            "episode_duration": 1e4,
            **({"fmu": str(transformed_ssp(directory))} if transformed else {}),
        },
        "system": system,
        "actions": {"inputs": ["load.tau_ext"], "low": {"load.tau_ext": -1}, "high": {"load.tau_ext": 1}},
        "observations": {"outputs": ["load.omega"]},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    plant = SystemPlant(parse_experiment(data, source=directory / "bench.yaml"))
    plant.bind(["load.tau_ext"], ["load.omega"])
    if native:
        plant.reset({}, [0.0])
    else:  # the master decides at its first reset
        os.environ["FMU_BRIDGE_NO_NATIVE_MASTER"] = "1"
        try:
            plant.reset({}, [0.0])
        finally:
            del os.environ["FMU_BRIDGE_NO_NATIVE_MASTER"]
    assert (plant.master.native is not None) == native
    return plant


TYPED = ("real", "integer", "boolean", "enum")


def typed_plant(directory: Path, n: int, *, native: bool = True) -> SystemPlant:
    """``n`` typed FMUs (FMI 2.0) in a chain, each passing its Real, Integer, Boolean and
    Enumeration outputs to the next one's inputs (``c_i.integer_out -> c_{i+1}.integer_in``, ...):
    three of every four links are not Float64. ``native=False`` asks for the Python master; where
    the native master cannot serve the system, ``native=True`` gets the Python master too (the
    table then says which master ran)."""
    components = {f"c{i}": {"fmu": "example:typed:2.0"} for i in range(n)}
    connections = [f"c{i}.{t}_out -> c{i + 1}.{t}_in" for i in range(n - 1) for t in TYPED]
    inputs = [f"c0.{t}_in" for t in TYPED]
    data = {
        "model": {"step_size": H, "episode_duration": 1e4},
        "system": {"components": components, "connections": connections},
        "observations": {"outputs": [f"c{n - 1}.{t}_out" for t in TYPED]},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    plant = SystemPlant(parse_experiment(data, source=directory / f"typed{n}.yaml"))
    plant.bind(inputs, [f"c{n - 1}.{t}_out" for t in TYPED])
    if not native:
        os.environ["FMU_BRIDGE_NO_NATIVE_MASTER"] = "1"
    try:
        plant.reset({}, [0.5, 3.0, 1.0, 2.0])
    finally:
        os.environ.pop("FMU_BRIDGE_NO_NATIVE_MASTER", None)
    return plant


def ecos_simulation() -> tuple[object | None, str]:
    """The same two FMUs and connections in Ecos (its own master loop), or None and why not."""
    try:
        from ecospy import EcosSimulation, EcosSimulationStructure
    except (ImportError, OSError) as exc:
        return None, f"ecospy unavailable: {exc}"
    structure = EcosSimulationStructure()
    structure.add_model("motor", str(example_fmu("dcmotor", "2.0", "cs")))
    structure.add_model("load", str(example_fmu("gearload", "2.0", "cs")))
    structure.make_real_connection("motor::omega", "load::omega_in")
    structure.make_real_connection("load::torque", "motor::load_torque")
    structure.add_parameter_set("initial", {"motor::voltage": 12.0})
    simulation = EcosSimulation(structure=structure, step_size=H)
    simulation.init(parameter_set="initial")
    return simulation, ""


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
    parser.add_argument("--cpu-time", action="store_true", help="time by this thread's CPU time (see above)")
    args = parser.parse_args()
    in_process(args)
    if not args.no_distributed:
        from benchmarks.bench_system_nodes import distributed

        distributed([int(n) for n in args.nodes.split(",")], args.remote_steps)


def in_process(args: argparse.Namespace) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        plant = system_plant(Path(tmp))
        python_plant = system_plant(Path(tmp), native=False)
        plant10 = system_plant(Path(tmp), sample=10)
        transformed = system_plant(Path(tmp), transformed=True)
        transformed_python = system_plant(Path(tmp), native=False, transformed=True)
        typed = {
            f"typed{n}{'' if native else '_python'}": typed_plant(Path(tmp), n, native=native)
            for n in (2, 12)
            for native in (True, False)
        }
        motor, load = raw_pair()
        ecos, why = ecos_simulation()
        state = {"omega": 0.0, "torque": 0.0, "t": 0.0}

        def system(steps: int) -> None:
            for _ in range(steps):
                plant.step([0.0])

        def system10(steps: int) -> None:
            for _ in range(steps // 10):
                plant10.step([0.0])

        def python_master(steps: int) -> None:
            for _ in range(steps):
                python_plant.step([0.0])

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

        candidates = {"system": system, "system10": system10, "python": python_master, "raw": raw}
        candidates.update(
            units=_stepper(transformed, [0.0]), units_python=_stepper(transformed_python, [0.0])
        )
        for key, typed_system in typed.items():
            candidates[key] = _stepper(typed_system, [0.5, 3.0, 1.0, 2.0])
        if ecos is not None:
            step = ecos.step  # type: ignore[attr-defined]

            def ecos_each(steps: int) -> None:
                for _ in range(steps):
                    step(1)

            def ecos_all(steps: int) -> None:
                step(steps)

            candidates.update(ecos_each=ecos_each, ecos_all=ecos_all)
        clock = time.thread_time if args.cpu_time else time.perf_counter
        rates = interleaved(candidates, args.steps, args.repeats, clock)
        masters = {key: "native" if p.master.native is not None else "Python" for key, p in typed.items()}
        for closable in (plant, plant10, python_plant, transformed, transformed_python, motor, load):
            closable.close()
        for typed_system in typed.values():
            typed_system.close()
        if ecos is not None:
            ecos.terminate()  # type: ignore[attr-defined]
    report(rates, why)
    report_typed(rates, masters)


def _stepper(plant: SystemPlant, inputs: list[float]) -> Callable[[int], None]:
    def run(steps: int) -> None:
        for _ in range(steps):
            plant.step(inputs)

    return run


def report_typed(rates: dict[str, float], masters: dict[str, str]) -> None:
    """Typed links (Integer, Boolean, Enumeration): the native master against the Python one."""
    rows = []
    for n in (2, 12):
        ours, python = rates[f"typed{n}"], rates[f"typed{n}_python"]
        rows.append((f"{n} typed components, {masters[f'typed{n}']} master", fmt_us(ours), ""))
        rows.append((f"{n} typed components, Python master", fmt_us(python), f"{ours / python:.2f}"))
    print(table(rows, ("typed links, macro step", "us/step", "x the first row (Python / native)")))


def report(rates: dict[str, float], ecos_missing: str) -> None:
    """The table of :func:`in_process` and whether the targets are met."""
    raw_rate = rates["raw"]
    named = (
        ("SystemPlant, Jacobi, native master", "system"),
        ("native master, samples of 10 macro steps", "system10"),
        ("SystemPlant, Jacobi, Python master", "python"),
        ("units and a transformation, native master", "units"),
        ("units and a transformation, Python master", "units_python"),
    )
    rows = [("raw FMPy loop (2 FMUs)", fmt_us(raw_rate), "1.00", "")]
    rows += [(label, fmt_us(rates[key]), f"{raw_rate / rates[key]:.2f}", "") for label, key in named]
    if not ecos_missing:
        for key, label, ours in (
            ("ecos_each", "Ecos loop, step(1) per macro step", "system"),
            ("ecos_all", "Ecos loop, step(n)", "system10"),
        ):
            faster = rates[key] / rates[ours]
            rows.append((label, fmt_us(rates[key]), f"{raw_rate / rates[key]:.2f}", f"{faster:.2f}"))
    print(
        table(rows, ("in-process macro step", "us/step", "x raw", "x faster than ours (per call / batched)"))
    )
    ratio = raw_rate / rates["system"]
    print(f"target <= 1.3x raw: {'met' if ratio <= 1.3 else 'NOT met'}")
    cost = rates["system"] / rates["units"]
    print(
        f"target: units and a transformation <= 1.2x the plain native master: {cost:.2f}x, "
        f"{'met' if cost <= 1.2 else 'NOT met'}"
    )
    if ecos_missing:
        print(f"Ecos: {ecos_missing}")
    else:
        met = "met" if rates["units"] >= rates["ecos_each"] else "NOT met"
        print(f"target: units and a transformation, native, no slower than Ecos's plain step(1): {met}")
        for ours, theirs, what in (
            ("system", "ecos_each", "a macro step a call"),
            ("system10", "ecos_all", "many a call"),
        ):
            met = "met" if rates[ours] >= rates[theirs] else "NOT met"
            print(f"target: native master no slower than Ecos's loop, {what}: {met}")


if __name__ == "__main__":
    main()
