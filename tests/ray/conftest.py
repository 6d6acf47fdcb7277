"""Tests that need Ray (the ``ray`` extra, its own venv: ``.ci/ray``). Without Ray each module skips;
with ``FMU_BRIDGE_REQUIRE_RAY=1`` (set by ``.ci/ray``) a missing Ray fails the run instead."""

from __future__ import annotations

import os

if os.environ.get("FMU_BRIDGE_REQUIRE_RAY") == "1":
    import ray  # noqa: F401  (an ImportError here fails the run: these tests must run, not skip)
