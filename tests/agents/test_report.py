"""Reports a control engineer would sign: scenario and seeds filled in, termination bounds drawn as
lines, inputs as steps with a readable panel of their first samples at 50 Hz, units on every metric
axis, one legend per figure."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from agents.evaluate import EvaluationResult, evaluate
from agents.report import PlotSpec, metrics_figure, summary, trace_figure, write
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment

CARTPOLE = example_experiment("cartpole_balance")  # 50 Hz bang-bang force, bounds on x and theta


@pytest.fixture(scope="module")
def result() -> EvaluationResult:
    return evaluate(["random", "push=constant:10"], CARTPOLE, episodes=2, seed=5)


def test_scenario_and_seed_columns_are_filled(result: EvaluationResult, tmp_path: Path) -> None:
    rows = summary(result)
    assert [(r["scenario"], r["seeds"]) for r in rows] == [("nominal", "5-6"), ("nominal", "5-6")]
    paths = write(result, tmp_path, "cartpole", load_experiment(CARTPOLE))
    episodes = list(csv.DictReader(paths["csv"].open()))
    assert {(e["scenario"], e["seed"]) for e in episodes} == {("nominal", "5"), ("nominal", "6")}
    report = paths["report"].read_text()
    assert "| agent | scenario | episodes | seeds |" in report and "| nominal | 2 | 5-6 |" in report


def test_trace_figure_draws_references_bounds_steps_a_zoom_and_one_legend() -> None:
    motor = example_experiment("dcmotor_tracking")  # 100 Hz voltage, a reference, a current bound
    result = evaluate(["pid", "random"], motor, episodes=1, seed=3, scenarios=["step_up"])
    fig = trace_figure(result, "step_up", PlotSpec.of(load_experiment(motor), result))
    assert len(fig.legends) == 1 and all(ax.get_legend() is None for ax in fig.axes)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels.count("pid") == labels.count("random") == labels.count("termination bound") == 1
    assert "reference omega_ref" in labels
    by_signal = {
        ax.get_ylabel().split(" ")[0]: ax for ax in fig.axes if not ax.get_title().startswith("voltage:")
    }
    bounds = by_signal["current"].get_lines()
    assert sorted(line.get_ydata()[0] for line in bounds if line.get_label() == "termination bound") == [
        -40,
        40,
    ]
    assert by_signal["voltage"].get_lines()[0].get_drawstyle() == "steps-post"
    zoom = next(ax for ax in fig.axes if ax.get_title() == "voltage: the first 50 samples")
    steps = zoom.get_lines()[0]
    assert steps.get_drawstyle() == "steps-post" and len(steps.get_xdata()) == 51
    assert "(seed 3)" in fig.axes[0].get_title()


def test_metric_axes_have_units_and_the_figure_one_legend(result: EvaluationResult) -> None:
    spec = PlotSpec.of(load_experiment(CARTPOLE), result)
    fig = metrics_figure(summary(result), result, spec)
    assert len(fig.legends) == 1 and all(ax.get_legend() is None for ax in fig.axes)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels and all("[" in label and label.endswith("]") for label in labels), labels
    assert "return [sum of rewards]" in labels and "length [samples]" in labels


def test_the_zoom_panel_takes_episodes_shorter_than_itself() -> None:
    """The demo's case: the first agent runs past the zoom's 50 samples, another falls sooner."""
    pole = example_experiment("cartpole_continuous")
    result = evaluate(["random", "zero"], pole, episodes=1, seed=0)
    lengths = {r["agent"]: r["length"] for r in result.rows}
    assert lengths["random"] > 50 > lengths["zero"], lengths  # the case this test is about
    fig = trace_figure(result, "nominal", PlotSpec.of(load_experiment(pole), result))
    zoom = next(ax for ax in fig.axes if ax.get_title() == "force: the first 50 samples")
    assert sorted(len(line.get_xdata()) for line in zoom.get_lines()) == [lengths["zero"] + 1, 51]
