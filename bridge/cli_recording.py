"""Recording commands (record, replay, info, export) for the ``fmu-bridge`` app."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Add the recording commands to ``app`` (filled in with bridge.recording/bridge.replay)."""
    del app
