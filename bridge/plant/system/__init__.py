"""Systems of coupled FMUs: one plant made of several components joined by connections.

``description`` says what the system is (from the experiment's ``system:`` section, an SSP 1.0
``.ssp``/``.ssd`` read by ``ssp`` with ``ssm`` (parameter mappings) and ``ssb`` (signal
dictionaries, nested systems), or OSP's ``OspSystemStructure.xml`` read by ``osp``; ``runfile``
runs such a file as it is), ``check`` holds it against the FMUs with ``transform`` (units and
connection transformations), ``graph`` orders it and finds algebraic loops, ``master`` steps it
(Jacobi or Gauss-Seidel, multi-rate, optional fixed-point iteration; ``native_master``: the same
in one native call where it applies, made by ``bridge.fmu.system_step``, as every FMU call is made
in ``bridge.fmu``), ``component`` is one FMU of it in this process and ``plant`` is the
:class:`SystemPlant` the env drives. Variables of a system are named ``component.variable``.

May import the experiment, ``bridge.fmu`` and the plant interface; the network only lazily,
for components served by nodes.
"""
