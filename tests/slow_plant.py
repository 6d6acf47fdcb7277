"""The slow plant for tests: ``models/slow_plant`` (a first-order lag whose doStep sleeps
``step_delay_s`` and whose initialisation sleeps ``init_delay_s``) in an experiment file.

Tests keep the delays small (a few hundred ms per step, a few seconds of initialisation): enough to
be slower than every deadline a user did not set would allow, cheap on a loaded machine because
the plant sleeps instead of computing."""

from __future__ import annotations

from pathlib import Path

EXPERIMENT = """\
name: slow-plant
model:
  fmu: example:slow_plant:2.0:cs
  step_size: 0.1
  sampling_time: 0.1
  episode_duration: {duration}
  parameters: {{step_delay_s: {step_delay_s}, init_delay_s: {init_delay_s}, tau: 0.5}}
{extra}
actions: {{inputs: [u], low: {{u: -1}}, high: {{u: 1}}}}
observations: {{outputs: [x]}}
reward: {{terms: [{{signal: {{name: x, norm: squared, weight: -1.0}}}}]}}
randomization:
  parameters:
    x0: {{uniform: [-1.0, 1.0]}}
"""


def slow_experiment(
    folder: Path,
    *,
    step_delay_s: float = 0.2,
    init_delay_s: float = 0.0,
    duration_s: float = 0.5,
    model_extra: str = "",
    tail: str = "",
) -> Path:
    """An experiment file over the slow plant in ``folder``: ``duration_s`` / 0.1 samples per
    episode; ``model_extra`` is added to the model section (e.g. ``isolation: {timeout: 1}``),
    ``tail`` at the end (e.g. a training section)."""
    text = EXPERIMENT.format(
        duration=duration_s,
        step_delay_s=step_delay_s,
        init_delay_s=init_delay_s,
        extra=f"  {model_extra}" if model_extra else "",
    )
    path = folder / "slow_plant.yaml"
    path.write_text(text + tail)
    return path
