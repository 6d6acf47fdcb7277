"""The ``system:`` section of an experiment: several FMUs coupled by connections.

Components by name with their FMUs, connections written ``a.y -> b.u``, parameters per
component, and the master algorithm. Variables of a system are named ``component.variable``
everywhere else in the experiment (actions, observations, rewards, scenarios, termination).
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from bridge.experiment.model_settings import EXPERIMENT_KEYS, ModelSettings
from bridge.experiment.reward import RewardSection

FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
CONNECTION = re.compile(r"^\s*([A-Za-z_][\w]*)\.(\S+)\s*->\s*([A-Za-z_][\w]*)\.(\S+)\s*$")
SYSTEM_SUFFIXES = (".ssp", ".ssd")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ComponentSection(ModelSettings):
    """One FMU of the system: every key of a model (:class:`ModelSettings`, as under ``model:``)
    and its place in the system. ``step_size`` must divide the macro step (multi-rate); ``node``
    serves the component from a node of that name instead of this process."""

    fmu: str = Field(
        default="",
        description="Path to the .fmu (relative to the experiment file) or example:NAME; may be left "
        "out for a component of the SSP that model.fmu names",
    )
    feedthrough: bool | None = Field(
        default=None,
        description="whether an output depends directly on an input; default: the FMU's declared "
        "dependencies, else true (FMI's rule for undeclared dependencies)",
    )
    node: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _experiment_keys(cls, data: Any) -> Any:
        given = [key for key in EXPERIMENT_KEYS if isinstance(data, dict) and key in data]
        if given:
            key = given[0]
            raise ValueError(
                f"{key} is a setting of the whole experiment, not of one component: give it once as "
                f"model.{key} (a component takes every other key of model:)"
            )
        return data


class IterationSection(_Strict):
    """Fixed-point iteration of each macro step (with rollback of component states)."""

    max_iterations: Annotated[int, Field(ge=1, le=1000)] = 10
    tolerance: Annotated[float, Field(gt=0)] = 1e-10


class AgentSection(_Strict):
    """One agent of several in the system (``bridge.env.multi_agent``): the inputs it drives (its
    actions, in [-1, 1] scaled to ``low``/``high``), the outputs it observes, and its own reward
    (a ``reward:`` section as the experiment's, over its observations and any other output)."""

    inputs: list[str] = Field(min_length=1)
    low: dict[str, FiniteFloat] = {}
    high: dict[str, FiniteFloat] = {}
    observations: list[str] = Field(min_length=1)
    reward: dict[str, Any] = Field(description="as the experiment's reward: section (terms, expression)")

    @field_validator("reward")
    @classmethod
    def _reward(cls, value: dict[str, Any]) -> dict[str, Any]:
        RewardSection.model_validate(value)  # its errors, under system.agents.NAME.reward
        return value


class SystemSection(_Strict):
    """Components, connections and the master algorithm (``jacobi`` or ``gauss_seidel``)."""

    components: dict[str, ComponentSection] = {}
    connections: list[str] = []
    algorithm: Literal["jacobi", "gauss_seidel"] = "jacobi"
    iteration: IterationSection | None = None
    order: list[str] = Field(default=[], description="Gauss-Seidel order; default: from the graph")
    agents: dict[str, AgentSection] = Field(
        default={}, description="several agents in one system (PettingZoo ParallelEnv), by name"
    )
    feedthrough_outputs: Literal["held", "updated"] = Field(
        default="held",
        description="held: outputs at t+H as the FMUs computed them in the step, with the inputs "
        "held at their values of t (what libcosim, Ecos and FMPy report); updated: after the "
        "exchange, components with direct feedthrough get the inputs of t+H and their outputs are "
        "read again, so every output at t+H is of that one instant (in-process components only)",
    )

    @field_validator("components")
    @classmethod
    def _names(cls, value: dict[str, ComponentSection]) -> dict[str, ComponentSection]:
        bad = [name for name in value if not re.fullmatch(r"[A-Za-z_]\w*", name)]
        if bad:
            raise ValueError(f"component names are identifiers (letters, digits, _), got {bad}")
        return value

    @field_validator("agents")
    @classmethod
    def _agent_names(cls, value: dict[str, AgentSection]) -> dict[str, AgentSection]:
        bad = [name for name in value if not re.fullmatch(r"[A-Za-z_][\w-]*", name)]
        if bad:  # an agent's name is a topic segment of its recording and a file name of its policy
            raise ValueError(f"agent names are identifiers (letters, digits, _, -), got {bad}")
        return value

    @field_validator("connections")
    @classmethod
    def _connections(cls, value: list[str]) -> list[str]:
        for text in value:
            if not CONNECTION.match(text):
                raise ValueError(f"connection {text!r} is not of the form 'a.y -> b.u'")
        return value


def is_system_file(fmu: str) -> bool:
    """Whether ``model.fmu`` names an SSP archive, an SSD file or OSP's system structure
    (``*OspSystemStructure*.xml``) rather than one FMU."""
    name = fmu.lower().replace("\\", "/").rpartition("/")[2]
    return name.endswith(SYSTEM_SUFFIXES) or (name.endswith(".xml") and "ospsystemstructure" in name)
