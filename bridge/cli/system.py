"""``fmu-bridge system inspect|check|simulate|serve``: systems of coupled FMUs from the command line."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from bridge.cli.options import (
    ConnectOpt,
    IsolateOpt,
    ListenOpt,
    PrefixOpt,
    StepTimeoutOpt,
    ZenohConfigOpt,
    ZenohModeOpt,
    close_nodes,
    console,
    err_console,
    zenoh_options,
)
from bridge.experiment.config import Experiment, as_experiment
from bridge.experiment.system import is_system_file

system_app = typer.Typer(
    help="Systems of coupled FMUs: inspect, check, simulate, serve.", no_args_is_help=True
)
ExperimentArg = Annotated[
    Path, typer.Argument(help="An experiment file with a system: section, or an .ssp/.ssd itself.")
]
StepSizeOpt = Annotated[
    float | None,
    typer.Option("--step-size", help="Macro step [s] of an .ssp/.ssd (default: its DefaultExperiment)."),
]
NoFeedthroughOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--no-feedthrough",
        help="An .ssp/.ssd/OSP component whose outputs do not depend on its inputs at the same "
        "instant (system.components.NAME.feedthrough: false; repeatable).",
    ),
]
IterationsOpt = Annotated[
    int,
    typer.Option(
        "--iterations", min=1, help="An .ssp/.ssd/OSP run: fixed-point iterations (system.iteration)."
    ),
]


def _experiment(
    path: Path,
    step_size_s: float | None = None,
    duration_s: float | None = None,
    no_feedthrough: list[str] | None = None,
    iterations: int = 1,
) -> Experiment:
    """An experiment file, or an .ssp/.ssd/OSP file run as it is (every output observed, no
    actions), with the components ``no_feedthrough`` names and ``iterations`` applied."""
    if is_system_file(str(path)):
        from bridge.plant.system.runfile import ssp_experiment

        system: dict[str, Any] = {}
        if no_feedthrough:
            system["components"] = {name: {"feedthrough": False} for name in no_feedthrough}
        if iterations > 1:
            system["iteration"] = {"max_iterations": iterations}
        return ssp_experiment(path, step_size_s=step_size_s, duration_s=duration_s, system=system)
    if no_feedthrough or iterations > 1:
        from bridge.errors import ConfigError

        raise ConfigError(
            f"--no-feedthrough and --iterations apply to .ssp/.ssd/OSP files; an experiment file says "
            f"system.components.NAME.feedthrough and system.iteration itself [{path}]"
        )
    return as_experiment(path)


def _remote(
    zenoh_config: Path | None,
    listen: list[str] | None,
    connect: list[str] | None,
    zenoh_mode: str | None,
    prefix: str,
) -> Any:
    """Node components reached with the command's Zenoh options (a session only if one is used)."""
    from bridge.net.system_node import NodeComponents

    if zenoh_config is None and not listen and not connect and zenoh_mode is None:
        return NodeComponents(prefix=prefix)
    options = zenoh_options(zenoh_config, listen, connect, zenoh_mode=zenoh_mode)
    return NodeComponents(options=options, prefix=prefix)


def _open(experiment: Experiment, remote: Any, *, check: bool = True) -> Any:
    """The system's plant; with ``check``, the experiment's task checked against it (a plant checks
    no task: an env does, and these commands run the plant without one)."""
    from bridge.experiment.validate import check_experiment
    from bridge.plant.system.plant import SystemPlant

    plant = SystemPlant(experiment, remote=remote)
    try:
        if check:
            check_experiment(experiment, plant.info)
    except BaseException:
        plant.close()
        raise
    return plant


def summary(plant: Any) -> dict[str, Any]:
    """Components, connections, order and warnings of a system plant, as JSON-ready data."""
    system = plant.system
    return {
        "algorithm": system.algorithm,
        "macro_step_s": plant.timing.step_size_s,
        "iterations": system.max_iterations,
        "components": [
            {
                "name": n,
                "fmu": str(c.fmu),
                "model": plant.infos[n].model_name,
                "fmi": plant.infos[n].fmi_version,
                "feedthrough": plant.feedthrough[n],
                "step_size_s": c.step_size_s or plant.timing.step_size_s,
                "parameters": c.parameters,
            }
            for n, c in system.components.items()
        ],
        "connections": [str(c) for c in system.connections],
        "links": [_link(plant, c) for c in system.connections],
        "master": _master(plant),
        "warnings": plant.warnings,
    }


def _link(plant: Any, c: Any) -> dict[str, Any]:
    """A connection with its transformation, unit conversion and the map they compose."""
    from bridge.plant.system.transform import connection_units, describe

    source = plant.infos[c.source.component].element(c.source.variable)[0]
    target = plant.infos[c.target.component].element(c.target.variable)[0]
    units = connection_units(c, source, target, plant.system)
    t = c.transform
    return {
        "connection": str(c),
        "transformation": None
        if t is None
        else {
            "kind": t.kind,
            "factor": t.factor,
            "offset": t.offset,
            "entries": [list(e) for e in t.entries],
        },
        "units": None if units is None else {"from": units[0], "to": units[1]},
        "map": describe(c, plant.couplings.get(c)),
    }


def _master(plant: Any) -> dict[str, str]:
    """Which master steps the system, and why."""
    from bridge.plant.system.native_master import python_master_reason

    why = python_master_reason(plant.system, plant.plants, plant.couplings, plant.infos)
    if why is None:
        return {
            "runs": "native",
            "why": "every component an FMI 2.0/3.0 co-simulation FMU in this process "
            "without input clocks, numeric connections of any type, values unchanged or "
            "through an affine map",
        }
    return {"runs": "python", "why": why}


@system_app.command("inspect")
def inspect_system(  # noqa: PLR0917 (typer options)
    experiment: ExperimentArg,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
    dot: Annotated[Path | None, typer.Option(help="Write the connection graph as Graphviz DOT.")] = None,
    png: Annotated[Path | None, typer.Option(help="Draw the connection graph into a PNG.")] = None,
    step_size: StepSizeOpt = None,
    no_feedthrough: NoFeedthroughOpt = None,
    iterations: IterationsOpt = 1,
    zenoh_config: ZenohConfigOpt = None,
    listen: ListenOpt = None,
    connect: ConnectOpt = None,
    zenoh_mode: ZenohModeOpt = None,
    prefix: PrefixOpt = "fmu_bridge",
) -> None:
    """A table of components and connections, and a picture of the connection graph."""
    from bridge.plant.system.graph import to_dot

    exp = _experiment(experiment, step_size, None, no_feedthrough, iterations)
    with _open(exp, _remote(zenoh_config, listen, connect, zenoh_mode, prefix)) as plant:
        data = summary(plant)
        if dot is not None:
            dot.write_text(to_dot(plant.system, plant.feedthrough))
        if png is not None:
            from bridge.plant.system.picture import draw_graph

            draw_graph(plant.system, plant.feedthrough, png)
    if as_json:
        console.print_json(json.dumps(data))
        return
    table = Table("component", "model", "FMI", "step [s]", "feedthrough", title=f"{experiment}")
    table.add_column("fmu", overflow="fold")
    for c in data["components"]:
        row = (c["name"], c["model"], c["fmi"], f"{c['step_size_s']:g}", str(c["feedthrough"]), c["fmu"])
        table.add_row(*row)
    console.print(table)
    connections = Table(
        "connection", "units", "value", title=f"{data['algorithm']}, macro step {data['macro_step_s']:g} s"
    )
    for link in data["links"]:
        units = link["units"]
        connections.add_row(
            link["connection"], f"{units['from']} -> {units['to']}" if units else "", link["map"]
        )
    console.print(connections)
    master = data["master"]
    console.print(f"master: {master['runs']} ({master['why']})", highlight=False)
    for w in data["warnings"]:
        console.print(f"warning: {w}", highlight=False)


@system_app.command("check")
def check_system_cmd(  # noqa: PLR0917 (typer options)
    experiment: ExperimentArg,
    steps: Annotated[int, typer.Option(help="Samples to run after the checks.")] = 5,
    step_size: StepSizeOpt = None,
    no_feedthrough: NoFeedthroughOpt = None,
    iterations: IterationsOpt = 1,
    zenoh_config: ZenohConfigOpt = None,
    listen: ListenOpt = None,
    connect: ConnectOpt = None,
    zenoh_mode: ZenohModeOpt = None,
    prefix: PrefixOpt = "fmu_bridge",
) -> None:
    """Check every connection and name, then reset the system and run a few samples."""
    from bridge.env.fmu_env import FmuEnv

    exp = _experiment(experiment, step_size, None, no_feedthrough, iterations)
    plant = _open(exp, _remote(zenoh_config, listen, connect, zenoh_mode, prefix), check=False)
    try:
        env = FmuEnv(exp, plant=plant)  # checks the task against the plant
    except BaseException:
        plant.close()
        raise
    with env:
        plant = env.plant
        _, info = env.reset(seed=0)
        for _ in range(steps):
            *_, info = env.step(env.action_space.sample() * 0)
        for w in getattr(plant, "warnings", []):
            console.print(f"warning: {w}", highlight=False)
        n = len(plant.system.connections)  # type: ignore[attr-defined]
        console.print(
            f"ok: {plant.name}, {n} connections valid; t = {info['time_s']:g} s after {steps} samples"
        )


@system_app.command("simulate")
def simulate_system(  # noqa: PLR0917 (typer options)
    experiment: ExperimentArg,
    duration: Annotated[float | None, typer.Option(help="Seconds (default: the episode duration).")] = None,
    csv: Annotated[Path | None, typer.Option(help="Write every observed output over time to CSV.")] = None,
    every: Annotated[int, typer.Option(min=1, help="Print every n-th sample.")] = 10,
    set_input: Annotated[
        list[str] | None, typer.Option("--input", help="Hold a task input at a value: NAME=VALUE.")
    ] = None,
    step_size: StepSizeOpt = None,
    no_feedthrough: NoFeedthroughOpt = None,
    iterations: IterationsOpt = 1,
    zenoh_config: ZenohConfigOpt = None,
    listen: ListenOpt = None,
    connect: ConnectOpt = None,
    zenoh_mode: ZenohModeOpt = None,
    prefix: PrefixOpt = "fmu_bridge",
) -> None:
    """Run the system open loop (task inputs at their start values) and print its outputs.

    An .ssp/.ssd runs as it is: every numeric output observed, its DefaultExperiment's step and
    duration unless --step-size and --duration say otherwise."""
    from bridge.errors import BridgeError

    exp = _experiment(experiment, step_size, duration, no_feedthrough, iterations)
    names = list(exp.observations.outputs)
    rows: list[list[float]] = []
    with _open(exp, _remote(zenoh_config, listen, connect, zenoh_mode, prefix)) as plant:
        inputs = list(exp.actions.inputs)
        plant.bind(inputs, names)
        held = _held(set_input or [], inputs)
        start = [held.get(n, float(plant.info.variables[n].start or 0.0)) for n in inputs]
        total = round((duration or exp.model.episode_duration) / plant.timing.sampling_time_s)
        try:
            rows.append(
                [plant.time_s, *plant.reset({**exp.model.parameters, **exp.model.start_values}, start)]
            )
            for _ in range(total):
                rows.append([plant.time_s + plant.timing.sampling_time_s, *plant.step(start)])
        except BridgeError as exc:  # the rows done are the user's: written, and counted in the error
            if csv is not None:
                _write_csv(csv, names, rows)
            raise BridgeError(f"{exc}\n{_kept(rows, plant.timing.steps_per_sample, total, csv)}") from exc
    if csv is not None:
        _write_csv(csv, names, rows)
    table = Table("t [s]", *names, title=f"{experiment}")
    for r in rows[::every] + ([rows[-1]] if (len(rows) - 1) % every else []):
        table.add_row(*(f"{v:.6g}" for v in r))
    console.print(table)


def _write_csv(path: Path, names: list[str], rows: list[list[float]]) -> None:
    lines = [",".join(["time", *names])] + [",".join(f"{v:.17g}" for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")


def _kept(rows: list[list[float]], steps_per_sample: int, total: int, csv: Path | None) -> str:
    """What a failed run leaves: the samples done of ``total``, and where their rows are."""
    if not rows:
        return "the run failed at its reset: no macro step was done" + (
            f"; {csv} holds the header" if csv else ""
        )
    done = len(rows) - 1
    where = (
        f"{csv} holds their {len(rows)} rows (the start included)"
        if csv
        else "pass --csv FILE to keep their rows"
    )
    return (
        f"the run stopped after {done * steps_per_sample} macro steps ({done} of {total} samples, "
        f"t = {rows[-1][0]:g} s); {where}"
    )


def _held(items: list[str], inputs: list[str]) -> dict[str, float]:
    from bridge.errors import ConfigError

    held = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name not in inputs:
            raise ConfigError(
                f"--input {item!r}: expected NAME=VALUE with NAME one of actions.inputs {inputs}"
            )
        try:
            held[name] = float(value)
        except ValueError:
            raise ConfigError(f"--input {item!r}: {value!r} is not a number") from None
    return held


@system_app.command("serve")
def serve_system(  # noqa: PLR0917 (typer options)
    experiment: ExperimentArg,
    component: Annotated[
        list[str] | None, typer.Option("--component", help="Serve only this component (repeatable).")
    ] = None,
    zenoh_config: ZenohConfigOpt = None,
    listen: ListenOpt = None,
    connect: ConnectOpt = None,
    zenoh_mode: ZenohModeOpt = None,
    prefix: PrefixOpt = "fmu_bridge",
    step_size: StepSizeOpt = None,
    isolate: IsolateOpt = False,
    step_timeout: StepTimeoutOpt = 10.0,
) -> None:
    """Serve the components that have node: as FMU nodes (lockstep) until interrupted.

    Each component runs in an FmuNode named by its node: key, with the inputs and outputs the
    system connects (see docs/systems.md). Run it once per machine with --component to spread
    the components: each machine needs only the FMUs of the components it serves. The system's
    env then drives them over Zenoh. --isolate and --step-timeout apply to every served
    component, as to a single `fmu-bridge node`."""
    import signal
    import threading

    from bridge.net.node_setup import check_step_timeout
    from bridge.net.transport import ZenohOptions, open_session, session_mode
    from bridge.serving.system import served_components, start_nodes

    check_step_timeout(step_timeout)  # before the network, like the file's checks below

    mode = session_mode(zenoh_mode, tuple(listen or ()), tuple(connect or ()), zenoh_config)
    options = ZenohOptions(zenoh_config, mode, tuple(listen or ()), tuple(connect or ()))
    stop = threading.Event()
    served = served_components(_experiment(experiment, step_size), component or ())  # before the network
    session = open_session(options)
    try:
        nodes = start_nodes(
            served, prefix=prefix, session=session, isolate=isolate, step_timeout_s=step_timeout
        )
        try:
            # SIGTERM as Ctrl-C (a KeyboardInterrupt in the main thread, handled below): a handler that
            # takes a lock the interrupted main thread may hold could deadlock
            signal.signal(signal.SIGTERM, signal.default_int_handler)
            for n in nodes:
                err_console.print(
                    f"node {n.name!r} serving {n.served.title} on {n.keys.base}/*", highlight=False
                )
            err_console.print(f"{len(nodes)} component node(s) serving; Ctrl-C stops them", highlight=False)
            while not stop.wait(0.5):
                pass
        except KeyboardInterrupt:
            pass
        finally:
            close_nodes(nodes)  # exits at once (code 3) if a call into an FMU never returned
    finally:
        session.close()


def register(app: typer.Typer) -> None:
    app.add_typer(system_app, name="system")
