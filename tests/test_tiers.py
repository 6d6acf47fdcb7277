"""The test tiers (tests/tiers.py): what a test does decides its tier, and the fast tier stays fast."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

ROOT = Path(__file__).resolve().parents[1]
TIERS = {"slow", "integration", "ros", "ray"}


def tiers_by_test(pytester: pytest.Pytester, *files: str) -> dict[str, set[str]]:
    """The tiers tests/conftest.py gives each test of ``files`` (real test modules of this suite)."""
    items = pytester.inline_genitems(*(str(ROOT / f) for f in files), "-m", "", "-p", "no:cacheprovider")[0]
    return {item.nodeid.split("::", 1)[1]: {m.name for m in item.iter_markers()} & TIERS for item in items}


def test_a_helper_that_starts_a_process_makes_its_test_integration_and_training_makes_it_slow(
    pytester: pytest.Pytester,
) -> None:
    tiers = tiers_by_test(pytester, "tests/net/test_safe_default.py", "tests/agents/test_progress.py")
    # starts its node and router through the module's `cli` helper (subprocess.Popen two calls away)
    assert tiers["test_a_node_and_a_router_without_options_listen_on_loopback_only_and_do_not_scout"] == {
        "integration"
    }
    assert tiers["test_network_options_are_explicit"] == set()  # reads options in process: fast
    assert tiers["test_train_says_nothing_when_nothing_is_rounded"] == {"slow"}  # agents.train.train
    assert tiers["test_evaluate_from_the_command_line_shows_the_bar"] == {"integration"}  # subprocess.run
    # evaluate(..., workers=workers): worker processes only where the parameter is more than one
    assert tiers["test_evaluate_reports_episodes_done_of_the_total[1]"] == set()
    assert tiers["test_evaluate_reports_episodes_done_of_the_total[2]"] == {"integration"}


def test_a_session_fixture_that_exports_an_fmu_is_a_build_step_not_a_process_under_test(
    pytester: pytest.Pytester,
) -> None:
    # pythonfmu_heater2 and eta_ctrl_fmus start the exporter and pip inside `with build_step():`
    tiers = tiers_by_test(pytester, "tests/fmu/test_thirdparty.py")
    assert tiers["test_fmi2_string_parameter_and_reset_restore_defaults"] == set()
    assert tiers["test_dymola_export_cs_matches_fmpy_and_me_agrees"] == set()


def test_a_fixture_that_opens_a_zenoh_router_makes_its_test_integration(pytester: pytest.Pytester) -> None:
    tiers = tiers_by_test(pytester, "tests/plant/test_system_clocks.py")
    served = [name for name in tiers if name.startswith("test_") and "[" in name and "node" in name]
    assert served and all(tiers[name] >= {"integration"} for name in served), tiers


@pytest.mark.integration
def test_a_fast_tier_test_that_starts_a_process_fails_and_names_the_marker(pytester: pytest.Pytester) -> None:
    pytester.makeconftest(
        """
        import pytest
        from tiers import guard_fast_tier

        @pytest.hookimpl(wrapper=True)
        def pytest_runtest_call(item):
            return (yield from guard_fast_tier(item))
        """
    )
    pytester.makepyfile(
        test_hidden=textwrap.dedent(
            """
            import multiprocessing, subprocess, sys
            import pytest

            def start(argv):  # what tests/tiers.py cannot see: the call goes through a variable
                return getattr(subprocess, "run")(argv, check=True)

            def test_hidden_process():
                start([sys.executable, "-c", "pass"])

            def _nothing():
                pass

            def test_hidden_worker():
                worker = multiprocessing.get_context("spawn").Process(target=_nothing)
                worker.start()
                worker.join()

            @pytest.mark.integration
            def test_marked_process():
                start([sys.executable, "-c", "pass"])

            def test_in_process():
                assert sum(range(4)) == 6

            def test_builds_with_the_compiler():  # an example FMU's first build: a build step
                start(["gcc", "--version"])
            """
        )
    )
    result = pytester.runpytest_inprocess("-p", "no:cacheprovider", "-m", "")
    result.assert_outcomes(passed=3, failed=2)
    result.stdout.fnmatch_lines(
        [
            "*test_hidden_process is in the fast tier but started a process (subprocess.Popen: *"
            "mark it @pytest.mark.integration*",
            "*test_hidden_worker is in the fast tier but started a process (multiprocessing: *",
        ]
    )
