"""The control extra is optional: without scipy or OSQP the lqr and mpc baselines say how to install it."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

from bridge.errors import DependencyMissing
from bridge.experiment.config import load_experiment
from bridge.experiment.examples import example_experiment


@pytest.mark.parametrize("missing", ["scipy", "osqp"])
def test_mpc_without_its_packages_names_the_control_extra(
    missing: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    for name in [m for m in sys.modules if m == missing or m.startswith(f"{missing}.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, missing, None)  # `import missing` raises ImportError from here on
    for name in [m for m in sys.modules if m.startswith("bridge.control")]:
        monkeypatch.delitem(sys.modules, name)
    mpc = importlib.import_module("bridge.control.mpc")  # importing the module needs neither
    from agents.policies import make_policy
    from bridge.env.fmu_env import FmuEnv

    experiment = load_experiment(Path(example_experiment("vehicle_path")))
    env = FmuEnv(experiment)
    try:
        with pytest.raises(DependencyMissing, match=r'pip install "fmu-bridge\[control\]"') as info:
            policy = make_policy("mpc", {"mpc": experiment.evaluation.baselines["mpc"].settings()})
            policy.reset(env.unwrapped.task, 0)
    finally:
        env.close()
    assert info.value.package == missing
    assert mpc.__name__ == "bridge.control.mpc"
