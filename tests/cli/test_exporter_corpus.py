"""FMUs from real exporters, as registry packages ship them, from ``init`` to ``simulate`` unedited.

The corpus: the FMUs in gemseo-fmu 3.1.1's source distribution (OpenModelica 1.18 to 1.21 exports,
FMI 2.0 CS/ME, for Linux and for Windows; one PythonFMU3 export, FMI 3.0) and in modestpy 0.1.1's
(JModelica.org builds for Linux that declare canBeInstantiatedOnlyOncePerProcess and need
libgfortran.so.3, and a Dymola build for Windows). Each goes ``init -> check -> simulate`` with
the model as exported (``--policy start``), or is refused with the reason, in one paragraph. The
OpenModelica trajectories are compared with FMPy's default simulation. Downloads are cached under
``$FMU_BRIDGE_CACHE/thirdparty``; the tests are skipped, saying why, only when they cannot be fetched.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu

from bridge.cli.simulate import make_policy
from bridge.env.fmu_env import FmuEnv
from tests.conftest import _cache_dir

pytestmark = [pytest.mark.slow, pytest.mark.integration]

GEMSEO = "src/gemseo_fmu/problems/fmu_files/"
MODESTPY = "modestpy/test/resources/"
#: name -> (package, path in its sdist, None: runs | what the refusal says)
CORPUS: dict[str, tuple[str, str, str | None]] = {
    "om_add": ("gemseo-fmu==3.1.1", GEMSEO + "linux/add.fmu", None),
    "om_ramp": ("gemseo-fmu==3.1.1", GEMSEO + "linux/ramp.fmu", None),
    "om_mass_damper": ("gemseo-fmu==3.1.1", GEMSEO + "linux/Mass_Damper.fmu", None),
    "om_mass_spring_system": ("gemseo-fmu==3.1.1", GEMSEO + "linux/MassSpringSystem.fmu", None),
    "om_mass_spring_sub1": ("gemseo-fmu==3.1.1", GEMSEO + "linux/MassSpringSubSystem1.fmu", None),
    "om_mass_spring_sub2": ("gemseo-fmu==3.1.1", GEMSEO + "linux/MassSpringSubSystem2.fmu", None),
    "pythonfmu3_fmu3model": ("gemseo-fmu==3.1.1", GEMSEO + "linux/FMU3Model.fmu", None),
    "om_add_windows": (
        "gemseo-fmu==3.1.1",
        GEMSEO + "win32/add.fmu",
        r"has no binary for this platform \(linux64\): it ships win64",
    ),
    "jmodelica_simple2r1c": (
        "modestpy==0.1.1",
        MODESTPY + "simple2R1C/Simple2R1C_linux64.fmu",
        r"libgfortran\.so\.3: cannot open shared object file",
    ),
    "dymola_simple2r1c_windows": (
        "modestpy==0.1.1",
        MODESTPY + "simple2R1C/Simple2R1C_win64.fmu",
        r"has no binary for this platform \(linux64\): it ships win64",
    ),
}
MAY_RUN = {"jmodelica_simple2r1c"}  # refused without libgfortran 3 (gone from current distributions)
OPENMODELICA = [name for name in CORPUS if name.startswith("om_") and not name.endswith("_windows")]


def _sdist(package: str, cache: Path) -> Path:
    name, _, version = package.partition("==")
    stem = f"{name.replace('-', '_')}-{version}.tar.gz"
    if not (cache / stem).is_file():
        cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--no-binary", ":all:", package]
        try:
            subprocess.run([*cmd, "-d", str(cache)], capture_output=True, timeout=600, check=True)
        except (subprocess.SubprocessError, OSError) as exc:
            pytest.skip(f"{package}'s source distribution could not be downloaded (offline?): {exc}")
    if not (cache / stem).is_file():
        pytest.skip(f"{package}'s source distribution is not in the package index as {stem}")
    return cache / stem


@pytest.fixture(scope="session")
def exporter_fmus() -> dict[str, Path]:
    """Every FMU of the corpus, fetched once and cached."""
    cache = _cache_dir() / "exporters"
    cache.mkdir(parents=True, exist_ok=True)
    found = {name: cache / name / Path(rel).name for name, (_, rel, _) in CORPUS.items()}
    for package in sorted({package for package, _, _ in CORPUS.values()}):
        wanted = {n: rel for n, (p, rel, _) in CORPUS.items() if p == package and not found[n].is_file()}
        if not wanted:
            continue
        with tarfile.open(_sdist(package, cache)) as tar:
            for member in tar.getmembers():
                for name, rel in wanted.items():
                    data = tar.extractfile(member) if member.name.endswith("/" + rel) else None
                    if data is not None:
                        found[name].parent.mkdir(exist_ok=True)
                        found[name].write_bytes(data.read())
    missing = [n for n, p in found.items() if not p.is_file()]
    if missing:
        pytest.fail(f"the source distributions no longer ship {missing}: update CORPUS")
    return found


def cli(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "bridge.cli", *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, timeout=900, check=False, cwd=cwd)


@pytest.mark.parametrize("name", list(CORPUS))
def test_init_check_simulate_or_a_one_paragraph_refusal(
    name: str, exporter_fmus: dict[str, Path], tmp_path: Path
) -> None:
    refusal = CORPUS[name][2]
    experiment = tmp_path / "experiment.yaml"
    made = cli("init", exporter_fmus[name], "-o", experiment, cwd=tmp_path)
    assert made.returncode == 0, made.stdout + made.stderr
    checked = cli("check", experiment, "--policy", "start", "--steps", "2", cwd=tmp_path)
    said = checked.stdout + checked.stderr
    assert "Traceback" not in said and "standard input" not in said, said
    if checked.returncode != 0:
        assert refusal is not None, f"{name} should run:\n{said}"
        errors = [line for line in said.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and re.search(refusal, errors[0]), said
        return
    assert refusal is None or name in MAY_RUN, f"{name} should have been refused:\n{said}"
    ran = cli("simulate", experiment, "--policy", "start", "--no-record", cwd=tmp_path)
    assert ran.returncode == 0, ran.stdout + ran.stderr
    assert "end: time" in ran.stdout, ran.stdout


@pytest.mark.parametrize("name", OPENMODELICA)
def test_openmodelica_trajectories_equal_fmpys(
    name: str, exporter_fmus: dict[str, Path], tmp_path: Path
) -> None:
    fmu = exporter_fmus[name]
    experiment = tmp_path / "experiment.yaml"
    made = cli("init", fmu, "-o", experiment, cwd=tmp_path)
    assert made.returncode == 0, made.stdout + made.stderr
    samples = 200
    with FmuEnv(experiment) as env:
        policy = make_policy("start", env.task, 0)
        obs, _ = env.reset(seed=0)
        rows = []
        for _ in range(samples):
            obs, *_, info = env.step(policy(obs))
            rows.append(np.asarray(info["outputs"], dtype=np.float64))
        names, step_s, sample_s = list(env.output_names), env.timing.step_size_s, env.timing.sampling_time_s
    result = simulate_fmu(
        str(fmu),
        fmi_type="CoSimulation",
        step_size=step_s,
        output_interval=sample_s,
        stop_time=samples * sample_s,
        output=names,
    )
    theirs = np.array([[row[n] for n in names] for row in result[1 : samples + 1]])
    np.testing.assert_allclose(np.array(rows), theirs, rtol=1e-12, atol=1e-12)
