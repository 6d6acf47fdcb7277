"""The base of every experiment section: unknown keys rejected with "did you mean", values frozen.

Pydantic's own message for an unknown key is "Extra inputs are not permitted"; a user who typed
``timestep`` for ``timesteps`` needs the close matches and the keys the section takes instead, so
:class:`Strict` checks its keys itself before validation and :func:`format_validation_error`
turns every error into one line ``key: what is wrong (got value)``.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from pydantic_core import PydanticCustomError

FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
UNKNOWN_KEYS = "unknown_keys"
INVALID_KEY = "invalid_key"
_SHOWN_CHARS = 80  # a bad value is quoted up to this length: the message stays one readable line


class Strict(BaseModel):
    """A section of an experiment file: unknown keys are errors that suggest the known ones."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            known = [n for n, f in cls.model_fields.items() if not f.exclude]
            unknown = [k for k in data if k not in cls.model_fields]
            if unknown:
                hints = tuple((str(k), suggestion(str(k), known)) for k in unknown)
                raise PydanticCustomError(
                    UNKNOWN_KEYS,
                    "unknown keys {keys}",
                    {"keys": ", ".join(repr(k) for k, _ in hints), "hints": hints},
                )
        return data


def invalid(key: str, message: str) -> PydanticCustomError:
    """An error about ``key`` (dotted, below the model that raises it), for cross-field checks."""
    return PydanticCustomError(INVALID_KEY, "{key}: {message}", {"key": key, "message": message})


def suggestion(name: str, known: Iterable[str], what: str = "keys here") -> str:
    """``did you mean 'x'?`` with the close matches of ``name``, else the list of what is allowed."""
    names = list(known)  # in the order the section declares them
    close = difflib.get_close_matches(name, names, n=3, cutoff=0.6)
    allowed = f"{what}: {', '.join(names)}" if names else "this section takes no keys"
    if close:
        return f"did you mean {' or '.join(repr(c) for c in close)}? ({allowed})"
    return allowed


def format_validation_error(exc: ValidationError, source: Path | None, prefix: str = "") -> str:
    """Every error of ``exc`` on one line: the dotted key (after ``prefix``), what is wrong, the value."""
    lines: list[str] = []
    union_keys: set[str] = set()
    for error in exc.errors():
        key = prefix + _dotted(error["loc"])
        if any(_is_type_label(p) for p in error["loc"]):
            if key in union_keys:
                continue  # one line per key: the first union member's complaint is the telling one
            union_keys.add(key)
        if error["type"] == UNKNOWN_KEYS:
            for name, hint in error["ctx"]["hints"]:
                where = f"{key}.{name}" if key else name
                lines.append(f"  {where}: unknown key; {hint}")
            continue
        if error["type"] == "extra_forbidden":
            lines.append(f"  {key}: unknown key (check its spelling and indentation)")
            continue
        if error["type"] == INVALID_KEY and "ctx" in error:  # ours; pydantic's own has no ctx
            ctx = error["ctx"]
            lines.append(f"  {key + '.' if key else ''}{ctx['key']}: {ctx['message']}")
            continue
        message = error["msg"].removeprefix("Value error, ")
        lines.append(f"  {key or '(top level)'}: {message}{_shown(error.get('input'))}")
    where = f" [{source}]" if source else ""
    unique = list(dict.fromkeys(lines))
    return f"invalid experiment{where}:\n" + "\n".join(unique)


def _dotted(loc: tuple[int | str, ...]) -> str:
    text = ""
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        elif not _is_type_label(part):
            text += f".{part}" if text else part
    return text


def _is_type_label(part: int | str) -> bool:
    # pydantic names the member of a union it tried ("dict[str,tuple[float,float]]", "literal['a']",
    # "function-after[...]"): noise in a key a user should find in the file
    return isinstance(part, str) and ("[" in part or part in {"str", "int", "float", "bool", "none"})


def _shown(value: Any) -> str:
    if isinstance(value, dict):
        return ""
    if isinstance(value, float) and not math.isfinite(value):
        return f" (got {value})"
    text = repr(value)
    if len(text) > _SHOWN_CHARS:
        text = text[: _SHOWN_CHARS - 3] + "..."
    return f" (got {text})"
