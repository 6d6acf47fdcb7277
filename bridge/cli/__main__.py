"""``python -m bridge.cli``: the same as the ``fmu-bridge`` command."""

from bridge.cli.main import main

main()
