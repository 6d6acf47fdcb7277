"""The single and the batch Task are the same arithmetic whatever SIMD numpy dispatches to.

The bit-identity tests run again in subprocesses with ``NPY_DISABLE_CPU_FEATURES`` naming numpy's
AVX-512 targets, then its AVX2 targets as well, and each run first proves that the variable took
effect (the features it names read as absent in ``__cpu_features__`` there, present here)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

from tests.conftest import run_pytest

ROOT = Path(__file__).resolve().parents[2]
BIT_FOR_BIT = [
    "tests/task/test_codegen.py",
    "tests/env/test_batch_env.py::test_batch_vector_env_equals_sync_vector_env_over_fmu_envs_bit_for_bit",
    "tests/env/test_batch_env.py::test_batch_vec_env_equals_sb3_dummy_vec_env_bit_for_bit",
    "tests/env/test_me_fixed_step_env.py::test_batch_env_over_fixed_step_me_equals_single_envs",
    # our own models only (the FMU from another tool is downloaded and may be skipped offline)
    "tests/plant/test_batch_me.py::test_time_events_inside_samples",
    "tests/plant/test_batch_me.py::test_state_events_bounce_alike",
    "tests/plant/test_batch_me.py::test_one_instance_terminating_alone",
]


def _avx512(name: str) -> bool:  # numpy >= 2.4: X86_V4 and AVX512_*; before: AVX512F, AVX512_SKX, ...
    return name.startswith("AVX512") or name == "X86_V4"


def _avx2(name: str) -> bool:  # numpy >= 2.4: X86_V3; before: AVX2, FMA3, F16C
    return _avx512(name) or name in {"X86_V3", "AVX2", "FMA3", "F16C"}


def _disabled(group: str) -> list[str]:
    """numpy's dispatch targets of ``group`` this CPU has (only those can be disabled)."""
    keep = _avx512 if group == "avx512" else _avx2
    return [name for name in __cpu_dispatch__ if keep(name) and __cpu_features__.get(name)]


@pytest.mark.parametrize("group", ["avx512", "avx2"])
@pytest.mark.timeout(1200)  # above the subprocess's 900 s (about 90 s at load average 7 on 2 cores)
def test_bit_identity_holds_with_simd_groups_disabled(group: str, tmp_path: Path) -> None:
    names = _disabled(group)
    if not names:
        pytest.skip(
            f"this CPU has none of numpy's {group} dispatch targets ({__cpu_dispatch__}): nothing to disable"
        )
    env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": " ".join(names)}
    probe = "from numpy._core._multiarray_umath import __cpu_features__ as f; import json, sys; " + (
        "print(json.dumps({n: bool(f.get(n)) for n in sys.argv[1:]}))"
    )
    seen = subprocess.run(
        [sys.executable, "-c", probe, *names], env=env, capture_output=True, text=True, timeout=60, check=True
    )
    assert json.loads(seen.stdout) == dict.fromkeys(names, False), seen.stdout + seen.stderr
    run = run_pytest(BIT_FOR_BIT, tmp_path / "t", env, timeout_s=900)
    assert run.returncode == 0, (
        f"with NPY_DISABLE_CPU_FEATURES={env['NPY_DISABLE_CPU_FEATURES']!r}:\n{run.stdout[-4000:]}"
    )
    assert " passed" in run.stdout and "skipped" not in run.stdout, run.stdout[-2000:]
