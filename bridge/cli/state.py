"""``fmu-bridge state``: save an FMU's state to a file after running it to a time or to a steady
state (``save``), and show what a state file holds (``info``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from bridge.cli.options import console

state_app = typer.Typer(
    help="FMU state files: start every episode from a saved state (model.reset_policy: {state_file: ...}).",
    no_args_is_help=True,
)


@state_app.command("save")
def save(  # noqa: PLR0917 (typer options)
    experiment: Annotated[Path, typer.Argument(help="An experiment YAML file (its model section is used).")],
    output: Annotated[Path, typer.Option("--output", "-o", help="The state file to write.")],
    until: Annotated[
        float | None, typer.Option("--until", help="Run to this simulation time (s), then save.")
    ] = None,
    steady: Annotated[
        bool,
        typer.Option(
            "--steady",
            help="Run until the outputs and the state derivatives the FMU offers settle "
            "(see --tol, --window), then save.",
        ),
    ] = False,
    tol: Annotated[float, typer.Option(help="--steady: largest relative change over a window.")] = 1e-6,
    window: Annotated[float, typer.Option(help="--steady: window (s) of the change.")] = 1.0,
    max_time: Annotated[float, typer.Option(help="--steady: give up at this time (s).")] = 1e4,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Initialise the experiment's FMU, run it open loop to --until or --steady, and save its state."""
    from bridge.experiment.config import as_experiment
    from bridge.plant.state_run import save_state

    run = save_state(
        as_experiment(experiment),
        output,
        until_s=until,
        steady=steady,
        tol=tol,
        window_s=window,
        max_time_s=max_time,
    )
    if as_json:
        console.print_json(
            json.dumps(
                {
                    **_header(run.header),
                    "path": str(run.path),
                    "change": run.change,
                    "derivatives": run.derivatives,
                }
            )
        )
        return
    watched = f"; outputs and {run.derivatives}" if run.derivatives else "; outputs only"
    settled = f", settled (change {run.change:.3g}{watched})" if run.change is not None else ""
    console.print(
        f"saved the state of {run.header.model_name} at t = {run.header.time_s:g} s{settled} "
        f"({run.header.size} bytes): {run.path}",
        highlight=False,
        soft_wrap=True,
    )


@state_app.command("info")
def info(
    path: Annotated[Path, typer.Argument(help="A state file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Show whose state a file holds, where on the time grid it was saved, and check its checksum."""
    from bridge.fmu.state_file import read

    header = read(path).header  # read() checks sizes and the checksum
    if as_json:
        console.print_json(json.dumps({**_header(header), "path": str(path)}))
        return
    table = Table(show_header=False, box=None)
    table.add_column(no_wrap=True)
    table.add_column(overflow="fold")  # a checksum or a path is folded, never cut
    for key, value in _header(header).items():
        table.add_row(key, json.dumps(value) if isinstance(value, dict) else str(value))
    console.print(table)
    console.print(f"checksum OK: {path}", highlight=False, soft_wrap=True)


def _header(header: Any) -> dict[str, Any]:
    from dataclasses import asdict

    return asdict(header)


def register(app: typer.Typer) -> None:
    app.add_typer(state_app, name="state")
