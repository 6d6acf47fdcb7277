"""The sweep's grid (agents/sweep.py) without training: parsing and the points in report order."""

from __future__ import annotations

from pathlib import Path

import pytest

from agents.sweep import parse_grid, points
from bridge.errors import ConfigError
from bridge.experiment.examples import example_experiment


def test_grid_values_are_read_as_yaml_and_points_are_sets_times_seeds(tmp_path: Path) -> None:
    grid = parse_grid(["learning_rate=0.001,lin_0.01", "n_steps=32,64", "normalize=true"])
    assert grid == {"learning_rate": [0.001, "lin_0.01"], "n_steps": [32, 64], "normalize": [True]}
    todo = points(example_experiment("cartpole_balance"), seeds=[0, 1], grid=grid, out=tmp_path)
    assert len(todo) == 2 * 2 * 2
    assert [(dict(p.hyperparams)["n_steps"], p.seed) for p in todo[:4]] == [
        (32, 0),
        (32, 1),
        (64, 0),
        (64, 1),
    ]
    assert len({p.run_dir for p in todo}) == len(todo)


@pytest.mark.parametrize("item", ["learning_rate", "=1,2", "n_steps="])
def test_a_grid_item_that_is_not_name_equals_values_is_refused(item: str) -> None:
    with pytest.raises(ConfigError, match="NAME=V1,V2"):
        parse_grid([item])


def test_a_sweep_without_seeds_or_with_a_bad_experiment_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="at least one seed"):
        points(example_experiment("cartpole_balance"), seeds=[], grid={}, out=tmp_path)
    with pytest.raises(ConfigError):
        points(tmp_path / "missing.yaml", seeds=[0], grid={}, out=tmp_path)


def test_the_sweep_command_trains_evaluates_and_writes_the_report(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3")
    from typer.testing import CliRunner

    from bridge.cli.main import _load_plugins, app

    _load_plugins()
    out_dir = tmp_path / "sweep"
    args = ["sweep", str(example_experiment("cartpole_balance")), "--seeds", "0", "--timesteps", "64"]
    args += ["--n-envs", "1", "--eval-episodes", "2", "--out", str(out_dir)]
    args += ["--grid", "n_steps=32", "--grid", "batch_size=32", "--grid", "n_epochs=1"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output + repr(result.exception)
    lines = (out_dir / "sweep.csv").read_text().splitlines()
    assert lines[0].startswith("seed,n_steps,batch_size,n_epochs,mean_return") and len(lines) == 2
    assert (out_dir / "runs" / "p0-seed0" / "model.zip").is_file()
    bad = CliRunner().invoke(app, ["sweep", str(example_experiment("cartpole_balance")), "--seeds", "a,b"])
    assert bad.exit_code != 0 and "expected integers" in str(bad.exception)
    engine = CliRunner().invoke(app, ["sweep", str(example_experiment("cartpole_balance")), "--engine", "x"])
    assert engine.exit_code != 0 and "'local' or 'ray'" in str(engine.exception)
