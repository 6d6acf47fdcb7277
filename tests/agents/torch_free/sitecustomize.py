"""Makes torch and stable-baselines3 unimportable in the process whose PYTHONPATH holds this folder.

Python imports ``sitecustomize`` at start-up, before any code of the program runs. The finder
below sits first on ``sys.meta_path``: every attempt to import ``torch``, ``stable_baselines3`` or
one of their submodules raises ImportError, and is appended (module name and the importing
stack) to the file named by ``FMU_BRIDGE_BLOCKED_IMPORTS``, so a test can tell "never tried"
from "tried, caught the ImportError and carried on".
"""

from __future__ import annotations

import os
import sys
import traceback
from collections.abc import Sequence
from importlib.machinery import ModuleSpec
from types import ModuleType

BLOCKED = ("torch", "stable_baselines3")


class BlockedImports:
    """A meta path finder that refuses the blocked top-level packages."""

    def find_spec(
        self, name: str, path: Sequence[str] | None = None, target: ModuleType | None = None
    ) -> ModuleSpec | None:
        if name.partition(".")[0] not in BLOCKED:
            return None
        log = os.environ.get("FMU_BRIDGE_BLOCKED_IMPORTS")
        if log:
            with open(log, "a", encoding="utf-8") as out:
                out.write(f"import {name}\n{''.join(traceback.format_stack(limit=12))}\n")
        raise ImportError(f"{name} is blocked in this process (a torch-free deployment test)", name=name)


sys.meta_path.insert(0, BlockedImports())
