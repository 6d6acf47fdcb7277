"""`evaluate --engine ray` on two Ray nodes on 127.0.0.1: the grid scenario x agent x episode chunks
as Ray tasks gives the same rows and report as the single-machine evaluation with the same seeds."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("ray")

from agents.evaluate import evaluate
from agents.report import write
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment

AGENTS = ["pid", "random", "zero"]


def test_evaluation_grid_on_ray_equals_the_single_machine_one(ray_cluster: Any, tmp_path: Path) -> None:
    import ray

    assert len([n for n in ray.nodes() if n["Alive"]]) == 2
    config = example_experiment("dcmotor_tracking")
    common: dict[str, Any] = {"episodes": 3, "seed": 40, "scenarios": ["step_up"]}
    local = evaluate(AGENTS, config, **common)
    remote = evaluate(AGENTS, config, engine="ray", chunk_episodes=2, **common)
    assert [same_row(a, b) for a, b in zip(remote.rows, local.rows)] == [True] * len(local.rows)
    assert len(remote.rows) == len(local.rows) == 3 * len(AGENTS)
    assert [r["episode"] for r in remote.rows] == [0, 1, 2] * len(AGENTS)
    experiment = load_experiment(config)
    written = {}
    for name, result in (("local", local), ("ray", remote)):
        paths = write(result, tmp_path / name, title="evaluation", experiment=experiment)
        written[name] = {kind: Path(path).read_text() for kind, path in paths.items()}
    assert written["ray"] == written["local"]  # results.csv, results.json, report.md


def same_row(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Equal rows, NaN equal to NaN (a metric that does not apply, e.g. no rise time)."""
    return a.keys() == b.keys() and all(
        a[k] == b[k] or (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])) for k in a
    )


def test_ray_evaluation_refuses_recordings_and_bad_chunks(ray_cluster: Any, tmp_path: Path) -> None:
    config = example_experiment("dcmotor_tracking")
    with pytest.raises(ConfigError, match="--no-record"):
        evaluate(["zero"], config, engine="ray", record_dir=tmp_path)
    with pytest.raises(ConfigError, match="at least 1"):
        evaluate(["zero"], config, engine="ray", chunk_episodes=0, episodes=1)
    with pytest.raises(ConfigError, match="'local' or 'ray'"):
        evaluate(["zero"], config, engine="dask")


def test_the_evaluate_command_on_ray_writes_the_report(ray_cluster: Any, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from bridge.cli.main import _load_plugins, app

    _load_plugins()
    out = tmp_path / "eval"
    args = ["evaluate", "zero", "pid", "--config", str(example_experiment("dcmotor_tracking"))]
    args += ["--scenarios", "step_up", "--episodes", "2", "--engine", "ray", "--chunk-episodes", "1"]
    result = CliRunner().invoke(app, [*args, "--out", str(out)])
    assert result.exit_code == 0, result.output + repr(result.exception)
    lines = (out / "results.csv").read_text().splitlines()
    assert len(lines) == 1 + 2 * 2 and (out / "report.md").is_file()
    assert not (tmp_path / "recordings").exists() and not Path("recordings", out.name).exists()
