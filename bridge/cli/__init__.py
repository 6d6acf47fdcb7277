"""The ``fmu-bridge`` command line: thin typer shims over typed functions that are also the API.

Owns argument parsing, console output and exit codes. May import every other bridge package;
nothing in bridge imports it.
"""

from bridge.cli.main import app, main

__all__ = ["app", "main"]
