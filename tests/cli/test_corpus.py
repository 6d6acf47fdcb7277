"""Every FMU of the test corpus goes from ``init`` to ``check``, ``simulate`` and training unedited.

The corpus: FMUs from other exporters (pythonfmu for FMI 2.0, pythonfmu3 for FMI 3.0, JModelica
through the FMUs shipped in PyFMI 2.5's source distribution: FMI 1.0/2.0, CS/ME; Dymola through
eta-ctrl's source distribution) and our own models
for what those lack (time events with inputs in model exchange; FMI 3.0 Binary, 2-D arrays and
clocks; Modelica-style names in model exchange and FMI 3.0). Downloads are cached under
``$FMU_BRIDGE_CACHE/thirdparty``; a test is skipped, saying why, when they cannot be fetched.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tarfile
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from bridge.cli.main import app
from bridge.experiment.config import load_experiment
from tests.conftest import _cache_dir, example_fmu

pytestmark = pytest.mark.slow
runner = CliRunner()

#: FMUs inside PyFMI 2.5's sdist: (FMI version and interface, path in the archive).
PYFMI_FMUS = {
    "jmodelica_cs10": "src/pyfmi/examples/files/FMUs/CS1.0/bouncingBall.fmu",
    "jmodelica_me10": "src/pyfmi/examples/files/FMUs/ME1.0/bouncingBall.fmu",
    "jmodelica_cs20": "src/pyfmi/examples/files/FMUs/CS2.0/bouncingBall.fmu",
    "jmodelica_me20": "src/pyfmi/examples/files/FMUs/ME2.0/bouncingBall.fmu",
    "jmodelica_me10_win_only": "src/pyfmi/examples/files/FMUs/ME1.0/SecondOrder.fmu",
}


def _pyfmi_sdist(cache: Path) -> Path:
    """PyFMI 2.5's sdist through pip: its metadata step needs cython<3, numpy<1.24 and FMIL_HOME."""
    archives = sorted(cache.glob("[Pp]y[Ff][Mm][Ii]-2.5.tar.gz"))
    if archives:
        return archives[-1]
    venv, fmil = cache / "venv", cache / "no-fmil"
    (fmil / "lib").mkdir(parents=True, exist_ok=True)
    (fmil / "include").mkdir(exist_ok=True)
    pip = [str(venv / "bin" / "python"), "-m", "pip", "-q"]
    steps = [
        [sys.executable, "-m", "venv", str(venv)],
        [*pip, "install", "cython<3", "numpy<1.24", "wheel"],
        [*pip, "download", "--no-deps", "--no-build-isolation", "--no-binary", ":all:", "pyfmi==2.5"],
    ]
    env = {**os.environ, "FMIL_HOME": str(fmil)}  # the metadata step only checks the folder exists
    try:
        for cmd in steps:
            subprocess.run(cmd, cwd=cache, env=env, capture_output=True, timeout=600, check=True)
    except (subprocess.SubprocessError, OSError) as exc:
        pytest.skip(f"PyFMI 2.5's source distribution could not be downloaded (offline?): {exc}")
    archives = sorted(cache.glob("[Pp]y[Ff][Mm][Ii]-2.5.tar.gz"))
    if not archives:
        pytest.skip("PyFMI 2.5's source distribution is not in the package index")
    return archives[-1]


@pytest.fixture(scope="session")
def pyfmi_fmus() -> dict[str, Path]:
    """JModelica-exported FMUs shipped in PyFMI 2.5's source distribution (fetched once, cached)."""
    cache = _cache_dir() / "pyfmi"
    cache.mkdir(parents=True, exist_ok=True)
    found = {name: cache / f"{name}.fmu" for name in PYFMI_FMUS}
    if all(p.is_file() for p in found.values()):
        return found
    with tarfile.open(_pyfmi_sdist(cache)) as tar:
        for member in tar.getmembers():
            for name, rel in PYFMI_FMUS.items():
                data = tar.extractfile(member) if member.name.endswith(rel) else None
                if data is not None:
                    found[name].write_bytes(data.read())
    missing = [n for n, p in found.items() if not p.is_file()]
    if missing:
        pytest.skip(f"PyFMI 2.5's source distribution no longer ships {missing}")
    return found


def _fixture(name: str, key: str | None = None) -> Callable[[pytest.FixtureRequest], Path]:
    def get(request: pytest.FixtureRequest) -> Path:
        value = request.getfixturevalue(name)
        return Path(value[key] if key else value)

    return get


def _example(name: str, version: str, interface: str) -> Callable[[pytest.FixtureRequest], Path]:
    return lambda request: example_fmu(name, version, interface)


#: name -> (how to get the FMU, whether it has something to act on: an input or tunable parameter).
CORPUS: dict[str, tuple[Callable[[pytest.FixtureRequest], Path], bool]] = {
    "pythonfmu_heater2 (FMI 2.0 CS, typed inputs)": (_fixture("pythonfmu_heater2"), True),
    "pythonfmu3_heater3 (FMI 3.0 CS, Enumeration input)": (_fixture("pythonfmu_heater3"), True),
    "pythonfmu3_arrays3 (FMI 3.0 CS, arrays)": (_fixture("arrays3_fmu"), True),
    "pythonfmu_names2 (FMI 2.0 CS, locals only, Modelica names)": (_fixture("names2"), False),
    "pythonfmu_longrun2 (FMI 2.0 CS, a 1e8 s default experiment)": (_fixture("pythonfmu_longrun2"), True),
    "jmodelica_cs10 (FMI 1.0 CS, no inputs)": (_fixture("pyfmi_fmus", "jmodelica_cs10"), False),
    "jmodelica_me10 (FMI 1.0 ME, no inputs)": (_fixture("pyfmi_fmus", "jmodelica_me10"), False),
    "jmodelica_cs20 (FMI 2.0 CS, tunable parameter)": (_fixture("pyfmi_fmus", "jmodelica_cs20"), True),
    "jmodelica_me20 (FMI 2.0 ME, tunable parameter)": (_fixture("pyfmi_fmus", "jmodelica_me20"), True),
    "dymola_damped_oscillator (FMI 2.0 CS/ME, inputs)": (
        _fixture("eta_ctrl_fmus", "damped_oscillator"),
        True,
    ),
    "stair (FMI 1.0 ME, time events, Int32 input)": (_example("stair", "1.0", "me"), True),
    "stair (FMI 2.0 ME, time events, Int32 input)": (_example("stair", "2.0", "me"), True),
    "stair (FMI 3.0 ME, time events, Int32 input)": (_example("stair", "3.0", "me"), True),
    "typed (FMI 3.0 CS, every integer type)": (_example("typed", "3.0", "cs"), True),
    "typed3 (FMI 3.0 CS, arrays, Binary, clock)": (_example("typed3", "3.0", "cs"), True),
    "modelica_names (FMI 2.0 ME, Modelica names, states as locals)": (
        _example("modelica_names", "2.0", "me"),
        True,
    ),
    "modelica_names (FMI 3.0 CS, Modelica names)": (_example("modelica_names", "3.0", "cs"), True),
}


def _init(fmu: Path, folder: Path) -> Path:
    config = folder / "experiment.yaml"
    result = runner.invoke(app, ["init", str(fmu), "-o", str(config)])
    assert result.exit_code == 0, result.output
    return config


@pytest.mark.parametrize("entry", list(CORPUS))
def test_init_then_check_then_simulate_unedited(
    entry: str, request: pytest.FixtureRequest, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    get, _ = CORPUS[entry]
    config = _init(get(request), tmp_path)
    monkeypatch.chdir(tmp_path)
    checked = runner.invoke(app, ["check", str(config), "--steps", "3"])
    assert checked.exit_code == 0, checked.output
    # two episodes (a reset between them), one for the model whose episodes are 1e8 FMU steps of a
    # Python class (minutes each): running it, reset included, is what the corpus asks of it
    episodes = "1" if "longrun" in entry else "2"
    simulated = runner.invoke(app, ["simulate", str(config), "--episodes", episodes])
    assert simulated.exit_code == 0, simulated.output
    assert list((tmp_path / "recordings").glob("*.mcap")), "simulate records by default"


@pytest.mark.parametrize("entry", [name for name, (_, acts) in CORPUS.items() if acts])
def test_train_a_few_hundred_steps_unedited(
    entry: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    from agents.train import train

    get, _ = CORPUS[entry]
    config = _init(get(request), tmp_path)
    assert load_experiment(config).actions.inputs, "a model with something to act on gets actions"
    overrides = {
        "timesteps": 256,
        "n_envs": 1,
        "hyperparams": {"n_steps": 128, "batch_size": 64},
        "eval_every": 100_000,
        "checkpoint_every": 100_000,
    }
    result = train(config, overrides=overrides, run_dir=tmp_path / "run", progress=False)
    assert result.timesteps >= 256 and result.model_path.is_file()


@pytest.mark.parametrize("entry", list(CORPUS))
def test_no_value_init_writes_is_refused(entry: str, request: pytest.FixtureRequest, tmp_path: Path) -> None:
    """Every value init writes, those it suggests in comments included (the FMU's parameter
    defaults, written commented out), passes ``check`` when used."""
    from bridge.env.plants import model_info_for
    from bridge.experiment.validate import check_experiment

    get, _ = CORPUS[entry]
    config = _init(get(request), tmp_path)
    text = config.read_text()
    data = yaml.safe_load(text)
    suggested: dict[str, object] = {}
    lines = text.splitlines()
    if "  parameters: {}" in " ".join(lines):
        start = next(i for i, line in enumerate(lines) if line.startswith("  parameters: {}"))
        for line in lines[start + 1 :]:
            if not line.startswith(("  #   ", "                              #")):
                break
            if line.startswith("  #   "):  # '  #   "name": value  # description'
                ((name, value),) = yaml.safe_load("{" + line[6:].split("  #")[0] + "}").items()
                suggested[name] = value
    assert suggested or "  parameters: {}" not in text
    data["model"]["parameters"] = {**(data["model"].get("parameters") or {}), **suggested}
    edited = tmp_path / "with_suggestions.yaml"
    edited.write_text(yaml.safe_dump(data))
    experiment = load_experiment(edited)
    check_experiment(experiment, model_info_for(experiment))
    samples = experiment.model.episode_duration / experiment.model.sampling_time
    assert 1 <= samples <= 10_000 + 1e-6, "init aims at an episode of at most 10,000 samples"


def test_a_very_long_default_experiment_gets_a_runnable_episode_with_a_comment(
    pythonfmu_longrun2: Path, tmp_path: Path
) -> None:
    text = _init(pythonfmu_longrun2, tmp_path).read_text()
    model = yaml.safe_load(text)["model"]
    assert (model["step_size"], model["sampling_time"], model["episode_duration"]) == (0.01, 100.0, 1e6)
    assert "the default experiment runs 1e+08 s" in text and "shortened to 1e+06 s" in text
    assert "# sampling_time 100 s = 10,000 FMU steps" in text
    checked = runner.invoke(app, ["check", str(tmp_path / "experiment.yaml"), "--steps", "1"])
    assert checked.exit_code == 0, checked.output


@pytest.mark.parametrize("entry", [name for name, (_, acts) in CORPUS.items() if not acts])
def test_models_without_anything_to_act_on_get_an_observation_only_experiment(
    entry: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    get, _ = CORPUS[entry]
    text = _init(get(request), tmp_path).read_text()
    assert yaml.safe_load(text)["actions"] == {"inputs": []}
    assert "training needs something to act on" in text


def test_fmu_without_a_binary_for_this_platform_inits_and_is_refused_by_check_saying_so(
    pyfmi_fmus: dict[str, Path], eta_ctrl_fmus: dict[str, Path], tmp_path: Path
) -> None:
    for fmu in (pyfmi_fmus["jmodelica_me10_win_only"], eta_ctrl_fmus["kea_simplified"]):
        folder = tmp_path / fmu.stem
        folder.mkdir()
        assert runner.invoke(app, ["inspect", str(fmu)]).exit_code == 0
        config = _init(fmu, folder)
        result = subprocess.run(
            [sys.executable, "-m", "bridge.cli", "check", str(config)],
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        assert result.returncode == 2, result.stdout + result.stderr
        assert "has no binary for this platform" in result.stderr
        assert "Traceback" not in result.stderr
