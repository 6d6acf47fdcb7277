"""``fmu-bridge train, evaluate, compare, agent run, agent export``: added through an entry point."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from rich.console import Console

from bridge.cli.options import ZenohModeOpt

console = Console()


def register(app: typer.Typer) -> None:
    """Entry point ``fmu_bridge.commands``: add the training and evaluation commands."""
    app.command("train")(train_cmd)
    app.command("evaluate")(evaluate_cmd)
    app.command("sweep")(sweep_cmd)
    app.command("compare")(compare_cmd)
    app.command("tune")(tune_cmd)
    agent_app = typer.Typer(
        help="Trained agents: run a policy as a node, export it (ONNX, policy FMU).", no_args_is_help=True
    )
    agent_app.command("run")(agent_run_cmd)
    agent_app.command("check")(agent_check_cmd)
    # `fmu-bridge export` is the recordings' CSV/Parquet export: agents export under `agent`.
    export_app = typer.Typer(help="Export a trained run: ONNX graph or policy FMU.", no_args_is_help=True)
    export_app.command("onnx")(export_onnx_cmd)
    export_app.command("fmu")(export_fmu_cmd)
    agent_app.add_typer(export_app, name="export")
    app.add_typer(agent_app, name="agent")


def tune_cmd(
    config: Annotated[Path, typer.Argument(help="The experiment YAML file.")],
    baseline: Annotated[str, typer.Argument(help="A baseline of evaluation.baselines.")],
    param: Annotated[
        list[str], typer.Option("--param", help="A positive value to tune: kp, design.q.NAME (repeat).")
    ],
    iterations: Annotated[int, typer.Option(help="Objective evaluations (Nelder-Mead).")] = 100,
    seeds: Annotated[int, typer.Option(help="Episodes per training scenario (seeds 1000..).")] = 2,
    penalty: Annotated[float, typer.Option(help="held_iae: added per episode ending early.")] = 100.0,
    objective: Annotated[
        str, typer.Option(help="held_iae (tracking) or return (minus the task's episode return).")
    ] = "held_iae",
    write: Annotated[
        Path | None,
        typer.Option(help="Write the experiment with the tuned values here (default: CONFIG.tuned.yaml)."),
    ] = None,
    out: Annotated[Path | None, typer.Option(help="tuning.json (default: beside that file).")] = None,
    version: Annotated[str | None, typer.Option()] = None,
) -> None:
    """Tune a baseline's gains or weights on the training scenarios (held IAE or return; agents/tune.py)."""
    import json

    from agents.tune import tune, write_experiment

    result = tune(
        config, baseline, param, iterations=iterations, seeds=seeds, penalty=penalty, objective=objective,
        version=version,
        log=console.print,
    )  # fmt: skip
    target = write_experiment(config, result, write or config.with_suffix(".tuned.yaml"))
    report = out or target.with_suffix(".tuning.json")
    report.write_text(json.dumps(result.as_dict(), indent=1))
    best = ", ".join(f"{k} = {v:.5g}" for k, v in zip(result.parameters, result.best))
    console.print(f"objective: {result.objective}")
    console.print(
        f"{result.start_objective:.4f} -> {result.best_objective:.4f} "
        f"({len(result.evaluations)} evaluations, {result.wall_time_s:.0f} s): {best}"
    )
    console.print(f"experiment: {target}; tuning record: {report}")


def export_onnx_cmd(
    run: Annotated[Path, typer.Argument(help="A run directory (or model .zip) from `fmu-bridge train`.")],
    out: Annotated[Path | None, typer.Option("-o", "--out", help="Default: RUN/policy.onnx.")] = None,
) -> None:
    """The deployed policy as one ONNX graph: normalisation, network, action mapping, metadata."""
    from agents.export.onnx import export_onnx

    console.print(f"ONNX policy: {export_onnx(run, out)}")


def export_fmu_cmd(
    run: Annotated[Path, typer.Argument(help="A run directory (or model .zip) from `fmu-bridge train`.")],
    fmi: Annotated[str, typer.Option("--fmi", help="FMI version: 2 or 3.")] = "2",
    out: Annotated[Path | None, typer.Option("-o", "--out", help="Default: RUN/policy-fmi<N>.fmu.")] = None,
) -> None:
    """The deployed policy as a co-simulation FMU (C from the weights, compiled with gcc)."""
    from agents.export.policy_fmu import export_fmu

    console.print(f"policy FMU: {export_fmu(run, fmi, out)}")


def safe_inputs(values: list[float] | None, n_inputs: int) -> list[float]:
    """``--safe-value``: one value for every action input, or one per action input (in order)."""
    from bridge.errors import ConfigError

    given = list(values or [0.0])
    if len(given) == 1:
        return given * n_inputs
    if len(given) != n_inputs:
        raise ConfigError(
            f"--safe-value: {len(given)} values for {n_inputs} action inputs; give one value for all "
            "of them or one per action input, in the order of actions.inputs"
        )
    return given


def agent_run_cmd(
    model: Annotated[Path, typer.Argument(help="A run directory or model .zip from `fmu-bridge train`.")],
    config: Annotated[
        Path | None, typer.Option("--config", help="Experiment (default: the run's copy).")
    ] = None,
    transport: Annotated[
        str, typer.Option(help="zenoh (native frames), ros2 (rmw_zenoh wire) or rclpy.")
    ] = "zenoh",
    node: Annotated[
        str, typer.Option("--node", help="The FMU node (zenoh) or ROS namespace of its topics.")
    ] = "fmu",
    observation_topic: Annotated[str | None, typer.Option(help="ROS: JointState topic to observe.")] = None,
    action_topic: Annotated[str | None, typer.Option(help="ROS: JointState topic to act on.")] = None,
    missing: Annotated[
        str, typer.Option(help="hold (the last action) or safe, when observations stop.")
    ] = "hold",
    safe_value: Annotated[
        list[float] | None,
        typer.Option(help="Safe physical input value(s) (--missing safe): one for all inputs, or one each."),
    ] = None,
    timeout_s: Annotated[
        float, typer.Option("--timeout", help="Seconds without observation before the rule.")
    ] = 0.5,
    scenario: Annotated[str | None, typer.Option(help="Scenario whose references the agent tracks.")] = None,
    duration_s: Annotated[
        float | None, typer.Option("--duration", help="Stop after this many seconds.")
    ] = None,
    prefix: Annotated[str, typer.Option("--prefix")] = "fmu_bridge",
    connect: Annotated[list[str] | None, typer.Option("--connect")] = None,
    listen: Annotated[list[str] | None, typer.Option("--listen")] = None,
    zenoh_config: Annotated[Path | None, typer.Option("--zenoh-config")] = None,
    zenoh_mode: ZenohModeOpt = None,
    ros_domain: Annotated[int | None, typer.Option(help="ROS_DOMAIN_ID (ros2 transport).")] = None,
    runtime: Annotated[
        str,
        typer.Option(
            help="torch (stable-baselines3), onnx (onnxruntime, no torch needed), fmu (the exported "
            "policy FMU, no torch needed) or baseline (MODEL names one of the --config experiment's "
            "evaluation.baselines, e.g. lqr)."
        ),
    ] = "torch",
    managed: Annotated[
        bool,
        typer.Option(
            "--managed/--unmanaged",
            help="rclpy: a lifecycle node that acts only once configured and activated (docs/ros2.md).",
        ),
    ] = False,
) -> None:
    """Run a trained policy as a node until Ctrl-C (or --duration); prints inference latency."""
    import signal
    import threading
    import time

    from agents.deploy import deployed_checkpoint
    from agents.deploy_io import AgentNode
    from bridge.net.transport import ZenohOptions, session_mode

    settings = agent_settings(
        model, config, transport, missing, safe_value, runtime,
        node=node,
        prefix=prefix,
        observation_topic=observation_topic,
        action_topic=action_topic,
        timeout_s=timeout_s,
        scenario=scenario,
        domain_id=ros_domain,
    )  # fmt: skip
    listen_t, connect_t = tuple(listen or ()), tuple(connect or ())
    mode = session_mode(zenoh_mode, listen_t, connect_t, zenoh_config)
    options = ZenohOptions(config_file=zenoh_config, mode=mode, listen=listen_t, connect=connect_t)
    started = time.monotonic()
    # SIGTERM as Ctrl-C: a KeyboardInterrupt in the main thread. Setting ``stop`` from the handler
    # could deadlock: the handler runs in the main thread, possibly while it holds the Event's lock
    # in ``stop.wait`` (seen: an agent that never exited after SIGTERM). Installed before the policy
    # loads: an agent stopped while it starts says so instead of vanishing without a word
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    console.print(
        f"agent deploys {deployed_checkpoint(model, runtime)}; loading it ({STARTING.get(runtime, runtime)})",
        highlight=False,
    )
    agent: Any
    try:
        if managed:
            from agents.deploy_lifecycle import ManagedAgent
            from bridge.errors import ConfigError

            if transport != "rclpy":
                raise ConfigError("--managed is a ROS 2 lifecycle node: use it with --transport rclpy")
            agent = ManagedAgent(model, config, settings)
            what = (
                f"managed agent {agent.ros.fully_qualified_name} (unconfigured: configure, then activate it)"
            )
        else:
            agent = AgentNode(model, config, settings, options)
            what = f"agent {model} acting on {node!r} over {transport} ({runtime})"
    except KeyboardInterrupt:
        console.print(
            f"agent stopped while starting, after {time.monotonic() - started:.1f} s (loading the "
            f"{runtime} policy): it took no observation and sent no action",
            highlight=False,
        )
        _leave_now()
    stop = threading.Event()
    console.print(f"agent ready after {time.monotonic() - started:.1f} s", highlight=False)
    console.print(f"{what}; Ctrl-C stops it", highlight=False)  # a line scripts wait for: kept as it was
    try:
        stats = agent.run(duration_s, stop)
    finally:
        agent.close()
    summary = stats.summary()
    console.print(
        f"{summary['observations']:.0f} observations, {summary['actions']:.0f} actions, "
        f"{summary['missing_events']:.0f} missing-observation events; inference latency median "
        f"{summary['latency_median_us']:.0f} us, p99 {summary['latency_p99_us']:.0f} us"
    )
    _leave_now()


STARTING = {
    "torch": "importing torch takes tens of seconds on a busy machine, a minute and more under heavy "
    "load; --runtime onnx or fmu need no torch and start sooner"
}
"""What an agent's start-up waits for, per runtime (said before it loads)."""


def _leave_now() -> NoReturn:
    """Exit at once, everything being closed: unloading torch and stable-baselines3 at interpreter
    shutdown takes seconds on a busy machine, and a stopped agent should be gone within one."""
    import logging
    import os
    import sys

    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def agent_check_cmd(
    run: Annotated[Path, typer.Argument(help="A run directory (or model .zip) from `fmu-bridge train`.")],
    recording: Annotated[
        Path, typer.Option("--recording", help="An evaluation recording (.mcap) to replay.")
    ],
    config: Annotated[
        Path | None, typer.Option("--config", help="The experiment the deployment uses (default: the run's).")
    ] = None,
    runtime: Annotated[str, typer.Option(help="torch, onnx or fmu (the exported policy FMU).")] = "torch",
    tolerance: Annotated[float, typer.Option(help="The largest action difference that passes.")] = 1e-6,
) -> None:
    """Replay a recording through the deployed runtime: action differences, latency, mapping mismatches.

    Exits 1 when an action differs by more than --tolerance or the mapping (joint names, order,
    scale, offset) differs from the trained one."""
    from agents.check import check_deployment

    report = check_deployment(run, recording, config=config, runtime=runtime, tolerance=tolerance)
    from bridge.cli.inspect import print_rows

    rows = [
        ["samples replayed", f"{report.samples} ({report.compared} with a recorded action)"],
        ["largest action difference", f"{report.max_action_difference:.3g} (tolerance {tolerance:g})"],
        ["samples over tolerance", str(report.differing)],
        *([f"inference latency {name}", f"{value:.0f} us"] for name, value in report.latency_us.items()),
        *(["mapping", problem] for problem in report.mapping),
    ]
    print_rows(console, ["check", "result"], rows, f"agent check: {run} ({runtime}) against {recording}")
    if not report.ok:
        console.print("[bold red]check failed[/bold red]: the deployment does not act as recorded")
        raise typer.Exit(1)
    console.print("check passed: the deployment acts as recorded")


def agent_settings(
    model: Path,
    config: Path | None,
    transport: str,
    missing: str,
    safe_values: list[float] | None,
    runtime: str,
    **fields: Any,
) -> Any:
    """The ``DeploySettings`` of ``agent run`` (checked; safe values one per action input)."""
    from agents.deploy import DeploySettings, deployment_experiment
    from bridge.errors import ConfigError
    from bridge.net.ros2.args import current as current_ros_args

    if transport not in ("zenoh", "ros2", "rclpy") or missing not in ("hold", "safe"):
        raise ConfigError("--transport is zenoh, ros2 or rclpy; --missing is hold or safe")
    if runtime not in ("torch", "onnx", "fmu", "baseline"):
        raise ConfigError(f"--runtime {runtime!r} is unknown; use torch, onnx, fmu or baseline")
    experiment, _ = deployment_experiment(model, config)
    n_inputs = len(experiment.actions.inputs)
    ros = current_ros_args()  # from ros2 launch: namespace, parameters, topic remappings
    if ros.namespace is not None:
        fields["namespace"] = ros.namespace
    for key in ("observation_topic", "action_topic"):
        topic = fields.get(key)
        if topic in ros.remaps:
            fields[key] = ros.remaps[topic]
    if "domain_id" in ros.parameters:
        fields["domain_id"] = int(ros.parameters["domain_id"])
    return DeploySettings(
        transport=transport,  # type: ignore[arg-type]  # checked above
        missing=missing,  # type: ignore[arg-type]  # checked above
        safe_inputs=safe_inputs(safe_values, n_inputs) if missing == "safe" else None,
        runtime=runtime,  # type: ignore[arg-type]  # checked above
        **fields,
    )


def train_cmd(
    experiment: Annotated[
        Path | None, typer.Argument(help="An experiment YAML file (with --resume: the run's copy).")
    ] = None,
    algo: Annotated[str | None, typer.Option(help="PPO, SAC, TD3, A2C or DQN.")] = None,
    timesteps: Annotated[int | None, typer.Option(help="Environment steps to train for.")] = None,
    n_envs: Annotated[int | None, typer.Option("--n-envs", help="Parallel environments.")] = None,
    vec: Annotated[str | None, typer.Option(help="dummy, subproc, remote or batch.")] = None,
    seed: Annotated[int | None, typer.Option()] = None,
    run_dir: Annotated[Path | None, typer.Option("--run-dir", help="Where the run goes.")] = None,
    resume: Annotated[Path | None, typer.Option(help="A run directory to continue.")] = None,
    version: Annotated[str | None, typer.Option("--version", help="Env version.")] = None,
    nodes: Annotated[str | None, typer.Option(help="Remote node name pattern (with --vec remote).")] = None,
    connect: Annotated[list[str] | None, typer.Option("--connect", help="Zenoh endpoint (remote).")] = None,
    zenoh_config: Annotated[Path | None, typer.Option("--zenoh-config")] = None,
    zenoh_mode: ZenohModeOpt = None,
    progress: Annotated[bool, typer.Option("--progress/--no-progress")] = True,
    residual: Annotated[
        str | None,
        typer.Option(help="Residual RL over an evaluation baseline: BASELINE:SCALE (e.g. pid:0.1)."),
    ] = None,
    fmu: Annotated[
        str,
        typer.Option(
            "--fmu",
            help="How the run folder's experiment names the FMU: absolute (its absolute path) or copy "
            "(a copy in the run folder, so the run outlives the original).",
        ),
    ] = "absolute",
    engine: Annotated[
        str,
        typer.Option(help="sb3 (stable-baselines3), or rllib: PPO or SAC on Ray, n_envs FMUs per runner."),
    ] = "sb3",
    runners: Annotated[
        int | None, typer.Option(help="RLlib env runners (with --engine rllib; default 1, or the run's).")
    ] = None,
    ray_address: Annotated[
        str | None, typer.Option("--ray-address", help="Ray cluster (default: $RAY_ADDRESS, else local).")
    ] = None,
    sample_timeout_s: Annotated[
        float | None,
        typer.Option(
            "--sample-timeout-s",
            help="RLlib: seconds an env runner may take for one sample (training.sample_timeout_s; "
            "default: as long as the plant takes).",
        ),
    ] = None,
) -> None:
    """Train an SB3 agent on an experiment (in-process, subprocess workers, or remote nodes).

    ``--resume RUN`` continues a run with its own experiment and settings; options given on the
    command line (e.g. ``--timesteps``: how many more steps) override the stored ones."""
    from agents.train import train
    from bridge.errors import ConfigError

    if experiment is None and resume is None:
        raise ConfigError("give an experiment file to train on, or --resume RUN_DIR to continue a run")
    if engine not in ("sb3", "rllib"):
        raise ConfigError(f"--engine must be sb3 or rllib, got {engine!r}")
    if engine == "rllib":
        given: dict[str, Any] = {"algo": algo.upper() if algo else None, "timesteps": timesteps}
        given |= {"n_envs": n_envs, "seed": seed, "sample_timeout_s": sample_timeout_s}
        _train_rllib(experiment, given, run_dir, resume, version, runners, ray_address)
        return
    if sample_timeout_s is not None:
        raise ConfigError("--sample-timeout-s is an RLlib setting: use it with --engine rllib")

    overrides: dict[str, Any] = {
        "algo": algo.upper() if algo else None,
        "timesteps": timesteps,
        "n_envs": n_envs,
        "vec": vec,
        "seed": seed,
    }
    if residual is not None:
        overrides["residual"] = _residual_option(residual)
    if nodes or connect or zenoh_config or zenoh_mode:
        overrides["remote"] = {
            "nodes": nodes or "*",
            "connect": list(connect or []),
            "zenoh_config": str(zenoh_config) if zenoh_config else None,
            "zenoh_mode": zenoh_mode,
        }
    result = train(
        experiment,
        overrides=overrides,
        run_dir=run_dir,
        resume=resume,
        version=version,
        progress=progress,
        fmu=fmu,
    )
    console.print(
        f"trained {result.timesteps:,} steps in {result.wall_time_s:.1f} s "
        f"({result.timesteps / max(result.wall_time_s, 1e-9):,.0f} steps/s)"
    )
    console.print(f"run: {result.run_dir}\nmodel: {result.model_path}")


def _train_rllib(
    experiment: Path | None,
    overrides: dict[str, Any],
    run_dir: Path | None,
    resume: Path | None,
    version: str | None,
    runners: int | None,
    ray_address: str | None,
) -> None:
    from agents.rllib_train import train_rllib
    from bridge.errors import ConfigError

    if experiment is None and resume is None:
        raise ConfigError("train --engine rllib needs an experiment file, or --resume RUN")
    result = train_rllib(
        None if resume is not None else experiment,
        run_dir=run_dir,
        overrides=overrides,
        runners=runners,
        version=version,
        ray_address=ray_address,
        resume=resume,
    )
    console.print(
        f"trained {result.timesteps:,} steps in {result.iterations} iterations, {result.wall_time_s:.1f} s"
    )
    console.print(f"run: {result.run_dir}\ncheckpoint: {result.checkpoint}\nONNX policy: {result.onnx}")


def _residual_option(text: str) -> dict[str, Any]:
    """``--residual pid:0.1`` -> ``training.residual: {baseline: pid, scale: 0.1}``."""
    from bridge.errors import ConfigError

    name, _, scale = text.partition(":")
    try:
        return {"baseline": name, "scale": float(scale or 1.0)}
    except ValueError:
        raise ConfigError(f"--residual {text!r}: expected BASELINE:SCALE (e.g. pid:0.1)") from None


def evaluate_cmd(
    agents: Annotated[
        list[str],
        typer.Argument(
            help="Models/run dirs, baselines (zero, start, random, constant:V, "
            "names in evaluation.baselines) or python:module:function; NAME=AGENT names one."
        ),
    ],
    config: Annotated[Path, typer.Option("--config", help="The experiment YAML file.")],
    scenarios: Annotated[
        list[str] | None, typer.Option("--scenarios", help="Scenario names (repeat).")
    ] = None,
    episodes: Annotated[int | None, typer.Option(help="Episodes per scenario and agent.")] = None,
    workers: Annotated[int, typer.Option(help="Worker processes.")] = 1,
    seed: Annotated[int, typer.Option()] = 1000,
    out: Annotated[Path | None, typer.Option("--out", help="Directory for results and report.")] = None,
    record: Annotated[
        bool, typer.Option("--record/--no-record", help="MCAP recordings of every episode.")
    ] = True,
    version: Annotated[str | None, typer.Option("--version")] = None,
    batch: Annotated[
        bool, typer.Option("--batch", help="All episodes of a cell in one batch env (implies --no-record).")
    ] = False,
    engine: Annotated[
        str, typer.Option(help="local, or ray: chunks of episodes as Ray tasks (implies --no-record).")
    ] = "local",
    chunk_episodes: Annotated[int, typer.Option("--chunk-episodes", help="Episodes per Ray task.")] = 4,
    ray_address: Annotated[
        str | None, typer.Option("--ray-address", help="Ray cluster (default: $RAY_ADDRESS, else local).")
    ] = None,
    reference: Annotated[
        str | None,
        typer.Option("--reference", help="Agent the others are compared with, paired (default: the first)."),
    ] = None,
    metric: Annotated[
        str, typer.Option("--metric", help="Metric of the intervals and paired differences.")
    ] = "return",
) -> None:
    """Evaluate agents and baselines over scenarios: metrics table with bootstrap intervals, paired
    differences against a reference agent, results.csv/json, report."""
    import time

    from agents.evaluate import agent_names, evaluate
    from agents.progress import episode_bar
    from agents.report import (
        PAIRED_COLUMNS,
        SPREAD_COLUMNS,
        headline_columns,
        paired,
        paired_cells,
        spread_cells,
        summary,
        write,
    )

    names = agent_names(agents)
    if reference is not None and reference not in names:
        from bridge.errors import ConfigError

        raise ConfigError(
            f"--reference {reference!r} is not one of the evaluated agents {names}; name one of them"
        )
    out = out or Path("runs") / f"eval-{time.strftime('%Y%m%d-%H%M%S')}"
    with episode_bar() as progress:
        result = evaluate(
            agents,
            config,
            version=version,
            scenarios=scenarios,
            episodes=episodes,
            workers=workers,
            seed=seed,
            record_dir=Path("recordings") / out.name if record and not batch and engine != "ray" else None,
            batch=batch,
            progress=progress,
            engine=engine,
            chunk_episodes=chunk_episodes,
            ray_address=ray_address,
        )
    from bridge.experiment.config import load_experiment

    paths = write(
        result,
        out,
        title=f"Evaluation of {config.stem}",
        experiment=load_experiment(config),
        reference=reference,
        metric=metric,
    )
    rows = summary(result, metric)
    columns = headline_columns(rows)
    from bridge.cli.inspect import print_rows

    cells = [
        [row["agent"], row["scenario"], str(row["episodes"]), row["seeds"],
         *(f"{row.get(c, float('nan')):.4g}" for c in columns), row["end"]]
        for row in rows
    ]  # fmt: skip
    print_rows(
        console,
        ["agent", "scenario", "episodes", "seeds", *columns, "end"],
        cells,
        f"evaluation ({config.name})",
    )
    print_rows(
        console,
        ["agent", "scenario", "episodes", *SPREAD_COLUMNS],
        [[r["agent"], r["scenario"], str(r["episodes"]), *spread_cells(r, metric)] for r in rows],
        f"{metric}: median and 95% bootstrap intervals",
    )
    pairs = paired(result, reference, metric)
    if pairs:
        print_rows(
            console,
            PAIRED_COLUMNS,
            [paired_cells(p) for p in pairs],
            f"{metric}, paired by seed: agent - {pairs[0]['reference']}",
        )
    import json

    from agents.report import MARGIN_COLUMNS, margin_cells

    margins = json.loads(paths["json"].read_text()).get("margins", [])
    if margins:
        print_rows(
            console,
            MARGIN_COLUMNS,
            [margin_cells(m) for m in margins],
            "stability margins of the model-based designs (Kalman filter included)",
        )
    console.print(f"results: {paths['csv']}, {paths['json']}\nreport: {paths['report']}")
    for recording in result.recordings:
        console.print(f"recording: {recording}")


def sweep_cmd(
    experiment: Annotated[Path, typer.Argument(help="An experiment YAML file with a training section.")],
    seeds: Annotated[str, typer.Option(help="Training seeds, comma-separated.")] = "0",
    grid: Annotated[
        list[str] | None,
        typer.Option("--grid", help="NAME=V1,V2 over training.hyperparams (repeat for a grid)."),
    ] = None,
    timesteps: Annotated[int | None, typer.Option(help="Environment steps per run.")] = None,
    n_envs: Annotated[int | None, typer.Option("--n-envs", help="Parallel environments per run.")] = None,
    eval_episodes: Annotated[int, typer.Option("--eval-episodes", help="Episodes per evaluation.")] = 5,
    eval_seed: Annotated[int, typer.Option("--eval-seed", help="First evaluation seed.")] = 1000,
    engine: Annotated[str, typer.Option(help="local (one run after another) or ray (Ray tasks).")] = "local",
    ray_address: Annotated[
        str | None, typer.Option("--ray-address", help="Ray cluster (default: $RAY_ADDRESS, else local).")
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Directory for the runs and the report.")] = None,
    version: Annotated[str | None, typer.Option("--version", help="Env version.")] = None,
) -> None:
    """Train over seeds and a hyperparameter grid, evaluate each run: sweep.csv/json/md."""
    import time

    from agents.sweep import parse_grid, points, sweep, write_report
    from bridge.errors import ConfigError

    try:
        seed_list = [int(s) for s in seeds.split(",") if s.strip()]
    except ValueError:
        raise ConfigError(f"--seeds {seeds!r}: expected integers separated by commas (e.g. 0,1,2)") from None
    out = out or Path("runs") / f"sweep-{time.strftime('%Y%m%d-%H%M%S')}"
    todo = points(
        experiment,
        seeds=seed_list,
        grid=parse_grid(grid or []),
        out=out,
        version=version,
        timesteps=timesteps,
        n_envs=n_envs,
        eval_episodes=eval_episodes,
        eval_seed=eval_seed,
    )
    rows = sweep(todo, engine=engine, ray_address=ray_address)
    paths = write_report(rows, out, title=f"Sweep of {experiment.stem}")
    from bridge.cli.inspect import print_rows

    cells = [[f"{v:.4g}" if isinstance(v, float) else str(v) for v in row.values()] for row in rows]
    print_rows(console, list(rows[0].keys()), cells, f"sweep ({experiment.name}, {len(rows)} runs)")
    console.print(f"report: {paths['report']}\nresults: {paths['csv']}, {paths['json']}")


def compare_cmd(
    runs: Annotated[list[Path], typer.Argument(help="Run directories from `fmu-bridge train`.")],
    plot: Annotated[Path | None, typer.Option(help="Write learning curves to this PNG.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the rows as JSON.")] = False,
) -> None:
    """Training runs side by side: settings, time, and evaluation results during training."""
    import json
    import math

    from agents.compare import compare_runs
    from bridge.cli.inspect import print_rows

    rows, curves = compare_runs(runs)
    if as_json:
        plain = [
            {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in r.items()} for r in rows
        ]
        print(json.dumps(plain, indent=2))  # plain JSON for programs: NaN (no evaluation yet) is null
    else:
        columns = [
            "run",
            "algo",
            "seed",
            "timesteps",
            "wall [s]",
            "steps/s",
            "best eval",
            "last eval",
            "status",
        ]
        cells = [
            [r["run"], r["algo"], str(r["seed"]), f"{r['timesteps']:,}", f"{r['wall_time_s']:.0f}",
             f"{r['steps_per_s']:,.0f}", f"{r['best_eval']:.1f}", f"{r['last_eval']:.1f}", r["status"]]
            for r in rows
        ]  # fmt: skip
        print_rows(console, columns, cells, "training runs")
        from agents.compare import over_seeds
        from agents.stats import interval_text

        spread = over_seeds(rows, [r["setup"] for r in rows])
        if spread:
            spread_cells = [
                [g["runs"], g["algo"], g["seeds"], f"{g['last_mean']:.1f}",
                 interval_text(g["last_low"], g["last_high"]), f"{g['last_std']:.1f}",
                 f"{g['last_min']:.1f} .. {g['last_max']:.1f}"]
                for g in spread
            ]  # fmt: skip
            print_rows(
                console,
                ["runs", "algo", "seeds", "last eval mean", "95% CI", "std", "range"],
                spread_cells,
                "the same configuration over seeds",
            )
    if plot is not None:
        from agents.compare import plot_curves

        plot_curves(curves, plot)
        if not as_json:
            console.print(f"learning curves: {plot}")
