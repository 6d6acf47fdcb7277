"""Systems of coupled FMUs: one plant made of several components joined by connections.

``description`` says what the system is (from the experiment's ``system:`` section or an SSP 1.0
``.ssp``/``.ssd``, read by ``ssp``), ``check`` holds it against the FMUs, ``graph`` orders it and
finds algebraic loops, ``master`` steps it (Jacobi or Gauss-Seidel, multi-rate, optional
fixed-point iteration), ``component`` is one FMU of it in this process and ``plant`` is the
:class:`SystemPlant` the env drives. Variables of a system are named ``component.variable``.

May import the experiment, ``bridge.fmu`` and the plant interface; the network only lazily,
for components served by nodes.
"""
