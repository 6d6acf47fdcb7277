"""C for a policy FMU: the observation, VecNormalize, the MLP and the action mapping from the weights.

The generated ``model.c`` implements the four functions of the example-model framework
(``models/common/fmu_core.h``): ``model_evaluate`` computes the outputs from the inputs whenever
an input changed (the policy is stateless: outputs depend directly on inputs). The observation
is rounded to float32 where stable-baselines3 does it, the network runs in double precision.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agents.export.extract import PolicyParts

_ACTIVATION_C = {
    "tanh": "x = tanh(x);",
    "relu": "x = x > 0.0 ? x : 0.0;",
    "elu": "x = x > 0.0 ? x : expm1(x);",
}


@dataclass(frozen=True)
class InputScaling:
    """The Task's scaling of raw signals: ``clip((s - centre) * inv, -clip, clip)`` per element."""

    centre: Sequence[float]
    inv: Sequence[float]
    clip: float | None


def _array(name: str, values: np.ndarray) -> str:
    flat = ", ".join(repr(float(v)) for v in np.asarray(values, dtype=np.float64).reshape(-1))
    return f"static const double {name}[{max(values.size, 1)}] = {{{flat or '0.0'}}};"


def _network(parts: PolicyParts) -> tuple[list[str], list[str]]:
    """(static weight tables, statements) computing ``y`` from ``obs``."""
    tables: list[str] = []
    body: list[str] = []
    width = len(parts.observation_names)
    current = "obs"
    for k, op in enumerate(parts.ops):
        if op.kind == "linear":
            assert op.weight is not None and op.bias is not None  # set for linear ops by extract
            n_out, n_in = op.weight.shape
            tables += [_array(f"W{k}", op.weight), _array(f"B{k}", op.bias)]
            body += [
                f"    double h{k}[{n_out}];",
                f"    for (int o = 0; o < {n_out}; o++) {{",
                f"        double s = B{k}[o];",
                f"        for (int i = 0; i < {n_in}; i++) s += W{k}[o * {n_in} + i] * {current}[i];",
                f"        h{k}[o] = s;",
                "    }",
            ]
            current, width = f"h{k}", n_out
        else:
            body.append(
                f"    for (int i = 0; i < {width}; i++) {{ double x = {current}[i]; "
                f"{_ACTIVATION_C[op.kind]} {current}[i] = x; }}"
            )
    body.append(f"    const double* y = {current};")
    return tables, body


def _observation(parts: PolicyParts, inputs: Sequence[str], scaling: InputScaling | None) -> list[str]:
    n = len(parts.observation_names)
    lines = [f"    double obs[{n}];"]
    for i, c_input in enumerate(inputs):
        value = f"d->{c_input}"
        if scaling is not None:
            value = f"(d->{c_input} - {scaling.centre[i]!r}) * {scaling.inv[i]!r}"
            if scaling.clip is not None:
                value = f"fmin(fmax({value}, {-scaling.clip!r}), {scaling.clip!r})"
        lines.append(f"    obs[{i}] = (double)(float)({value});")
    if parts.obs_mean is not None and parts.obs_std is not None:
        clip = parts.obs_clip
        lines += [
            f"    for (int i = 0; i < {n}; i++) {{",
            "        double z = (obs[i] - OBS_MEAN[i]) / OBS_STD[i];",
            f"        obs[i] = (double)(float)fmin(fmax(z, {-clip!r}), {clip!r});",
            "    }",
        ]
    return lines


def _head(parts: PolicyParts, outputs: Sequence[str]) -> list[str]:
    if parts.discrete:
        assert parts.table is not None  # set for discrete heads by extract
        n_actions, n_inputs = parts.table.shape
        lines = [
            "    int best = 0;",
            f"    for (int i = 1; i < {n_actions}; i++) if (y[i] > y[best]) best = i;",
        ]
        return lines + [f"    d->{c} = TABLE[best * {n_inputs} + {j}];" for j, c in enumerate(outputs)]
    lines = []
    for j, c in enumerate(outputs):
        if parts.head == "clip":
            action = f"fmin(fmax(y[{j}], LOW[{j}]), HIGH[{j}])"
        elif parts.head == "unsquash":
            unsquashed = f"LOW[{j}] + (y[{j}] + 1.0) * (HIGH[{j}] - LOW[{j}]) / 2.0"
            action = f"fmin(fmax({unsquashed}, LOW[{j}]), HIGH[{j}])"
        else:
            squashed = f"tanh(y[{j}])" if parts.head == "squash" else f"y[{j}]"
            action = f"LOW[{j}] + 0.5 * ({squashed} + 1.0) * (HIGH[{j}] - LOW[{j}])"
        lines += [
            f"    double a{j} = {action};",
            f"    d->{c} = CENTRE[{j}] + HALF[{j}] * fmin(fmax(a{j}, -1.0), 1.0);",
        ]
    return lines


def model_c(
    parts: PolicyParts, inputs: Sequence[str], outputs: Sequence[str], scaling: InputScaling | None
) -> str:
    """``model.c`` of the policy FMU; ``inputs``/``outputs`` are the C names of the variables."""
    tables, network = _network(parts)
    constants = [
        _array("LOW", parts.low),
        _array("HIGH", parts.high),
        _array("CENTRE", parts.centre),
        _array("HALF", parts.half),
        _array("TABLE", parts.table if parts.table is not None else np.zeros(0)),
    ]
    if parts.obs_mean is not None and parts.obs_std is not None:
        constants += [_array("OBS_MEAN", parts.obs_mean), _array("OBS_STD", parts.obs_std)]
    header = [
        f"/* Policy FMU: {parts.algo} of experiment {parts.metadata.get('experiment')!s}. Generated by",
        " * fmu-bridge agent export fmu from the run's weights. Do not edit. */",
        '#include "fmu_core.h"',
        "",
        "#include <math.h>",
        "",
    ]
    evaluate = [
        "void model_evaluate(FmuInstance* inst) {",
        "    ModelData* d = &inst->s.d;",
        *_observation(parts, inputs, scaling),
        *network,
        *_head(parts, outputs),
        "}",
    ]
    rest = [
        "FmuStatus model_initialize(FmuInstance* inst) { (void)inst; return FMU_OK; }",
        "void model_event_update(FmuInstance* inst, FmuEventResult* ev) { (void)inst; (void)ev; }",
        "FmuStatus model_do_step(FmuInstance* inst, double h) { (void)inst; (void)h; return FMU_OK; }",
    ]
    unused = "__attribute__((unused)) "
    lines = [*header, *(unused + c for c in constants), *tables, "", *evaluate, "", *rest]
    return "\n".join(lines) + "\n"
