"""1,000 seeded mutations of every example experiment: a clear error or a sensible experiment.

Each mutant (keys deleted, renamed with typos or added; values of another type, infinite, NaN,
huge or negative; lists reversed; anchors shared or multiplied; the text cut at a random offset)
goes through ``load_experiment`` and ``check_experiment``; a sample also through ``fmu-bridge
check``. The outcome must be success or a BridgeError whose message names a key or the file,
never another exception; an accepted experiment must pass independent sanity checks. The counts
go to experiment_fuzz.json for the reliability table (see tests/reliability_table.py).
"""

from __future__ import annotations

import copy
import json
import math
import random
import re
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from bridge.cli.main import app
from bridge.errors import BridgeError
from bridge.experiment.config import MAX_SAMPLES, Experiment, load_experiment
from bridge.experiment.examples import example_experiment, example_names
from bridge.experiment.validate import check_experiment
from bridge.fmu.vocab import ModelInfo
from tests.conftest import check_with_model
from tests.reliability_table import counts_file

MUTANTS_PER_EXAMPLE = 1000
CLI_SAMPLE = 5  # accepted and as many rejected mutants per example also go through `fmu-bridge check`
REPORT = counts_file("experiment_fuzz.json")  # docs/reliability/ only on request (reliability_table.py)
NUMBERS = [math.inf, -math.inf, math.nan, 1e308, -1e308, 1e12, -1.0, 0.0, -0.0, 2**63, -(2**80)]
OTHERS: list[Any] = ["text", "", None, True, [], {}, [1, "a"], {"k": 1}, "1e3", "example:nothing"]


# -- mutations --------------------------------------------------------------------------------------
def containers(data: Any) -> list[Any]:
    """Every dict and list in ``data`` (the root first)."""
    found, stack = [], [data]
    while stack:
        node = stack.pop()
        if isinstance(node, dict | list):
            found.append(node)
            stack.extend(node.values() if isinstance(node, dict) else node)
    return found


def slots(data: Any) -> list[tuple[Any, Any]]:
    """(container, key or index) of every value in ``data``."""
    return [(c, k) for c in containers(data) for k in (list(c) if isinstance(c, dict) else range(len(c)))]


def typo(name: str, rng: random.Random) -> str:
    i = rng.randrange(max(len(name), 1))
    kind = rng.choice(["drop", "swap", "add", "double"])
    if kind == "drop" and len(name) > 1:
        return name[:i] + name[i + 1 :]
    if kind == "swap" and len(name) > 2:
        i = min(i, len(name) - 2)
        return name[:i] + name[i + 1] + name[i] + name[i + 2 :]
    if kind == "double":
        return name[:i] + name[i] + name[i:]
    return name[:i] + rng.choice("sxz_") + name[i:]


def mutate_data(data: dict[str, Any], rng: random.Random) -> str:
    """Apply one structural mutation to ``data`` in place; returns its kind."""
    places = slots(data)
    container, key = rng.choice(places)
    kind = rng.choice(["delete", "type", "number", "reverse", "typo", "unknown", "share"])
    if kind == "delete":
        del container[key]
    elif kind == "type":
        container[key] = copy.deepcopy(rng.choice(OTHERS))
    elif kind == "number":
        numeric = [(c, k) for c, k in places if isinstance(c[k], int | float) and not isinstance(c[k], bool)]
        container, key = rng.choice(numeric or places)
        container[key] = rng.choice(NUMBERS)
    elif kind == "reverse":
        lists = [c for c in containers(data) if isinstance(c, list)]
        if lists:
            rng.choice(lists).reverse()
    elif kind in ("typo", "unknown"):
        dicts = [c for c in containers(data) if isinstance(c, dict) and c]
        target = rng.choice(dicts)
        name = rng.choice(list(target))
        if kind == "typo" and isinstance(name, str):
            target[typo(name, rng)] = target.pop(name)
        else:
            target[rng.choice(["extra", "colour", "timestep", 7, "metricz"])] = rng.choice(NUMBERS + OTHERS)
    else:  # one value in two places: yaml.safe_dump writes an anchor and an alias
        other_container, other_key = rng.choice(places)
        value = other_container[other_key]
        if all(c is not container for c in containers(value)):  # a tree still, not a cycle
            container[key] = value
    return kind


BOMB = "\n".join(
    ["bomb0: &b0 [ha, ha, ha, ha, ha, ha, ha, ha, ha, ha]"]
    + [f"bomb{i}: &b{i} [{', '.join([f'*b{i - 1}'] * 10)}]" for i in range(1, 8)]
)


DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def mutant(text: str, parsed: dict[str, Any], rng: random.Random) -> tuple[str, str]:
    """A mutated copy of an experiment file's text (``parsed``: its data) and the mutations applied."""
    roll = rng.random()
    if roll < 0.12:
        return text[: rng.randrange(len(text))], "truncate"
    if roll < 0.16:
        section = rng.choice(["training", "evaluation", "recording", "node", "ros", "model"])
        return f"{text}\n{section}:\n" + "\n".join("  " + line for line in BOMB.splitlines()), "bomb"
    data = copy.deepcopy(parsed)
    kinds = [mutate_data(data, rng) for _ in range(rng.randint(1, 3))]
    return yaml.dump(data, Dumper=DUMPER, sort_keys=False, allow_unicode=True), "+".join(kinds)


# -- what "sensible" means, checked independently of the validators --------------------------------
def finite_everywhere(value: Any, path: str = "") -> list[str]:
    if isinstance(value, float):
        return [] if math.isfinite(value) else [path]
    if isinstance(value, dict):
        return [
            p for k, v in value.items() if k != "hyperparams" for p in finite_everywhere(v, f"{path}.{k}")
        ]
    if isinstance(value, list | tuple):
        return [p for i, v in enumerate(value) for p in finite_everywhere(v, f"{path}[{i}]")]
    return []


def nonsense(exp: Experiment, info: ModelInfo) -> list[str]:
    """What would be wrong with an accepted experiment: the reasons, or nothing."""
    found = [f"not finite: {p}" for p in finite_everywhere(exp.model_dump())]
    pairs = [*exp.termination.bounds.items(), *exp.evaluation.metrics.constraints.items()]
    if isinstance(exp.observations.scale, dict):
        pairs += list(exp.observations.scale.items())
    for name in exp.actions.inputs:
        pairs.append((name, (exp.actions.low.get(name), exp.actions.high.get(name))))
    found += [f"bounds of {n}: {b}" for n, b in pairs if None not in b and not b[0] < b[1]]  # type: ignore[operator]
    step = exp.model.sampling_time or exp.model.step_size or info.default_experiment.step_size_s or 0
    durations = [exp.model.episode_duration, *(s.episode_duration or 0 for s in exp.scenarios.values())]
    found += [f"{d} s is over {MAX_SAMPLES} samples" for d in durations if step and d / step > MAX_SAMPLES]
    return found


# -- the run -----------------------------------------------------------------------------------------
KEYISH = re.compile(r"[A-Za-z_]\w*(\.\w+|\[\d+\])*:")


def outcome(path: Path, info: ModelInfo, fmu: str) -> tuple[str, str]:
    """('accepted', '') or ('rejected', message); anything else raises and fails the test."""
    try:
        experiment = load_experiment(path)
        if fmu and experiment.model.fmu == fmu:  # a system (no model.fmu) is read again
            check_experiment(experiment, info)
        else:
            check_with_model(experiment)
    except BridgeError as exc:
        return "rejected", str(exc)
    wrong = nonsense(experiment, info)
    assert not wrong, f"accepted a nonsensical experiment {path.read_text()!r}: {wrong}"
    return "accepted", ""


def cli_check(path: Path) -> int:
    """`fmu-bridge check`'s exit code as main() gives it: 2 for a BridgeError, never a traceback."""
    result = CliRunner().invoke(app, ["check", str(path), "--steps", "1"], env={"COLUMNS": "200"})
    if isinstance(result.exception, BridgeError):
        return 2
    assert result.exception is None or isinstance(result.exception, SystemExit), (
        f"`check` raised {result.exception!r} on {path.read_text()!r}"
    )
    return result.exit_code


@pytest.mark.slow  # 1000 mutants per example: minutes in all, a soak rather than a unit test
@pytest.mark.parametrize("name", example_names())
def test_mutated_experiments_give_a_clear_error_or_a_sensible_experiment(name: str, tmp_path: Path) -> None:
    source = example_experiment(name)
    text = source.read_text()
    parsed = yaml.safe_load(text)
    original = load_experiment(source)
    info = check_with_model(original)
    rng = random.Random(f"experiment-fuzz-{name}")
    counts: Counter[str] = Counter()
    cli_runs = Counter[int]()
    for _ in range(MUTANTS_PER_EXAMPLE):
        mutated, kinds = mutant(text, parsed, rng)
        path = tmp_path / f"{name}.yaml"  # beside nothing else: relative paths resolve the same way
        path.write_text(mutated)
        result, message = outcome(path, info, original.model.fmu)
        counts[result] += 1
        counts[f"kind:{kinds.split('+')[0]}"] += 1
        if result == "rejected":
            assert KEYISH.search(message) or str(path) in message, (
                f"vague message {message!r} for {mutated!r}"
            )
        if cli_runs[0 if result == "accepted" else 2] < CLI_SAMPLE:
            code = cli_check(path)
            assert code == (0 if result == "accepted" else 2), f"check exited {code} on {mutated!r}"
            cli_runs[code] += 1
    assert counts["accepted"] + counts["rejected"] == MUTANTS_PER_EXAMPLE
    assert counts["rejected"] > MUTANTS_PER_EXAMPLE // 4  # the mutations do reach the validators
    record(name, counts, cli_runs)


def record(name: str, counts: Counter[str], cli_runs: Counter[int]) -> None:
    """Merge this example's counts into the report file (one entry per example)."""
    REPORT.parent.mkdir(parents=True, exist_ok=True)
    report = json.loads(REPORT.read_text()) if REPORT.is_file() else {}
    report.setdefault(
        "description", "seeded mutations of each example experiment file (tests/experiment/test_fuzz.py)"
    )
    report.setdefault("examples", {})[name] = {
        "mutations": counts["accepted"] + counts["rejected"],
        "rejected_cleanly": counts["rejected"],
        "accepted_and_sensible": counts["accepted"],
        "tracebacks": 0,
        "cli_check_runs": sum(cli_runs.values()),
        "cli_check_exit_codes": {str(k): v for k, v in sorted(cli_runs.items())},
        "by_first_mutation": {
            k.removeprefix("kind:"): v for k, v in sorted(counts.items()) if k.startswith("kind:")
        },
    }
    examples = report["examples"].values()
    report["total"] = {
        key: sum(e[key] for e in examples)
        for key in ("mutations", "rejected_cleanly", "accepted_and_sensible", "tracebacks", "cli_check_runs")
    }
    REPORT.write_text(json.dumps(report, indent=2, sort_keys=True) + "\n")
