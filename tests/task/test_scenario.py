"""Scenarios, profiles, distributions and schedules against hand-computed values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bridge.experiment.config import Distribution, Profile, parse_experiment
from bridge.task.scenario import ScenarioSampler, draw, draw_many, evaluate

T = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0])


def profile(**spec: object) -> Profile:
    return Profile.model_validate(spec)


def test_step_ramp_sine_table_profiles(tmp_path: Path) -> None:
    np.testing.assert_array_equal(
        evaluate(profile(step={"time": 1.0, "before": 2, "after": 5}), T, tmp_path), [2, 2, 5, 5, 5, 5]
    )
    np.testing.assert_allclose(
        evaluate(profile(ramp={"start_time": 1.0, "end_time": 2.0, "start": 0, "end": 10}), T, tmp_path),
        [0, 0, 0, 5, 10, 10],
    )
    sine = evaluate(profile(sine={"amplitude": 2, "frequency_hz": 0.25, "offset": 1}), T, tmp_path)
    np.testing.assert_allclose(sine, 1 + 2 * np.sin(2 * np.pi * 0.25 * T))
    table = {"time": [0, 1, 2], "value": [0, 10, 0]}
    np.testing.assert_allclose(evaluate(profile(table=table), T, tmp_path), [0, 5, 10, 5, 0, 0])
    np.testing.assert_allclose(
        evaluate(profile(table={**table, "interpolation": "hold"}), T, tmp_path), [0, 0, 10, 10, 0, 0]
    )
    summed = profile(constant=1.0, add=[{"step": {"time": 2.0, "after": 3.0}}])
    np.testing.assert_allclose(evaluate(summed, T, tmp_path), [1, 1, 1, 1, 4, 4])
    assert Profile.model_validate(7.5).constant == 7.5


def test_csv_profile_and_its_errors(tmp_path: Path) -> None:
    (tmp_path / "load.csv").write_text("time,torque\n0,0\n1,0.5\n2,0.5\n")
    spec = profile(csv={"file": "load.csv", "column": "torque"})
    np.testing.assert_allclose(evaluate(spec, T, tmp_path), [0, 0.25, 0.5, 0.5, 0.5, 0.5])
    with pytest.raises(Exception, match=r"needs columns 'time' and 'speed'"):
        evaluate(profile(csv={"file": "load.csv", "column": "speed"}), T, tmp_path)


def test_distributions_are_seeded_and_respect_bounds() -> None:
    specs = [
        Distribution(uniform=(1.0, 2.0)),
        Distribution(normal=(0.0, 1.0)),
        Distribution(truncnormal=(0.0, 1.0, -0.5, 0.5)),
        Distribution(lognormal=(2.0, 0.1)),
        Distribution(choice=[1.0, 2.0, 3.0], weights=[0.0, 1.0, 0.0]),
    ]
    for spec in specs:
        a = [draw(spec, np.random.default_rng(5)) for _ in range(3)]
        b = [draw(spec, np.random.default_rng(5)) for _ in range(3)]
        assert a == b
    rng = np.random.default_rng(0)
    assert all(1.0 <= draw(specs[0], rng) <= 2.0 for _ in range(1000))
    assert all(-0.5 <= draw(specs[2], rng) <= 0.5 for _ in range(1000))
    assert {draw(specs[4], rng) for _ in range(50)} == {2.0}
    lognormal = draw_many(specs[3], rng, 20000)
    assert np.median(lognormal) == pytest.approx(2.0, rel=0.01)
    assert np.std(draw_many(specs[1], rng, 20000)) == pytest.approx(1.0, rel=0.03)


def _experiment(mode: str, **schedule: object) -> object:
    return parse_experiment(
        {
            "model": {"fmu": "example:dcmotor", "episode_duration": 1.0},
            "actions": {"inputs": ["voltage"]},
            "observations": {"outputs": ["omega"]},
            "reward": {"terms": [{"alive": 1.0}]},
            "scenarios": {"a": {}, "b": {"parameters": {"J": 0.02}}, "c": {}},
            "schedule": {"mode": mode, **schedule},
            "randomization": {"parameters": {"R": {"uniform": [0.9, 1.1]}}},
        }
    )


def sampler(mode: str, **schedule: object) -> ScenarioSampler:
    return ScenarioSampler(_experiment(mode, **schedule), lambda d: np.arange(101) * 0.01)  # type: ignore[arg-type]


def test_schedules() -> None:
    rng = np.random.default_rng(0)
    assert [sampler("fixed").choose(rng) for _ in range(3)] == ["a", "a", "a"]
    rr = sampler("round_robin", training=["b", "c"])
    assert [rr.choose(rng) for _ in range(4)] == ["b", "c", "b", "c"]
    weighted = sampler("weighted", weights={"a": 0.0, "b": 3.0, "c": 1.0})
    counts = {n: 0 for n in "abc"}
    for _ in range(4000):
        counts[weighted.choose(rng)] += 1
    assert counts["a"] == 0 and counts["b"] / counts["c"] == pytest.approx(3.0, rel=0.15)
    uniform = sampler("random")
    assert {uniform.choose(rng) for _ in range(100)} == {"a", "b", "c"}


def test_episode_merges_values_and_draws() -> None:
    s = sampler("fixed", training=["b"])
    spec = s.episode(np.random.default_rng(1))
    assert spec.scenario == "b" and spec.values["J"] == 0.02
    assert 0.9 <= spec.values["R"] <= 1.1 and spec.drawn == {"R": spec.values["R"]}
    assert spec.n_samples == 100


def _episode_rows(env: object, **reset: object) -> tuple[str, np.ndarray]:
    """One whole episode of a fixed action: its scenario and every observation."""
    obs, info = env.reset(**reset)  # type: ignore[attr-defined]
    rows, done = [obs], False
    while not done:
        obs, _, terminated, truncated, _ = env.step(np.array([0.4], dtype=np.float32))  # type: ignore[attr-defined]
        rows.append(obs)
        done = terminated or truncated
    return info["scenario"], np.asarray(rows)


def test_a_repeated_episode_is_the_drawn_one_and_a_forced_scenario_in_between_ends_the_repeat(
    tmp_path: Path,
) -> None:
    """A task whose episodes are all one (nothing drawn, no profile, no noise) reuses the last
    episode at reset; a scenario forced by a reset in between (evaluation) ends that, and the
    next plain reset is the training episode again, exactly as a fresh env's."""
    from bridge.env.fmu_env import FmuEnv

    data = {
        "model": {"fmu": "example:dcmotor", "episode_duration": 0.5},
        "actions": {"inputs": ["voltage"]},
        "observations": {"outputs": ["omega"], "scale": "none"},
        "reward": {"terms": [{"alive": 1.0}]},
        "scenarios": {"light": {}, "heavy": {"episode_duration": 1.0, "parameters": {"J": 0.05}}},
        "schedule": {"training": ["light"], "evaluation": ["heavy"]},
    }
    exp = parse_experiment(data, source=tmp_path / "e.yaml")
    with FmuEnv(exp) as env, FmuEnv(exp) as fresh:
        assert env.task.sampler.repeats()
        first = _episode_rows(env, seed=1)
        again = _episode_rows(env)
        heavy = _episode_rows(env, options={"scenario": "heavy"})
        after = _episode_rows(env)
        assert [first[0], again[0], heavy[0], after[0]] == ["light", "light", "heavy", "light"]
        assert len(heavy[1]) == 2 * len(first[1]) - 1 and not np.array_equal(heavy[1][5], first[1][5])
        for rows in (again, after):
            np.testing.assert_array_equal(rows[1], first[1])
        np.testing.assert_array_equal(_episode_rows(fresh, options={"scenario": "heavy"})[1], heavy[1])


@pytest.mark.parametrize(
    "extra",
    [
        {"randomization": {"parameters": {"R": {"uniform": [0.9, 1.1]}}}},
        {"scenarios": {"a": {}, "b": {}}},
        {"scenarios": {"a": {"references": {"omega_ref": 1.0}}}},
    ],
    ids=["a-drawn-value", "two-scenarios", "a-reference-profile"],
)
def test_episodes_that_draw_or_choose_do_not_repeat(extra: dict[str, object]) -> None:
    data = {
        "model": {"fmu": "example:dcmotor", "episode_duration": 1.0},
        "actions": {"inputs": ["voltage"]},
        "observations": {"outputs": ["omega"]},
        "reward": {"terms": [{"alive": 1.0}]},
        **extra,
    }
    exp = parse_experiment(data)
    assert not ScenarioSampler(exp, lambda d=None: np.linspace(0.0, 1.0, 11)).repeats()  # type: ignore[arg-type]
