"""Exporting a trained run as a deployable policy: one ONNX graph, or a policy FMU (C, FMI 2.0/3.0).

:mod:`~agents.export.extract` reads a run directory into the pieces every export needs (the
VecNormalize statistics, the deterministic action path of the network, the action mapping and
the names); :mod:`~agents.export.onnx` writes the ONNX graph through ``torch.onnx.export``;
:mod:`~agents.export.ccode` and :mod:`~agents.export.policy_fmu` generate C from the weights and
build the FMU with gcc. The Task's observation processing (selection, scaling, history) stays
in the caller (``agents.deploy``), so every runtime sees the same observation vector.
"""
