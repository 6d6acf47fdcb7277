"""torch's thread count for the network being trained.

An RL policy is small: SB3's default MlpPolicy (64 x 64, actor and critic) has about 10k
parameters, so one matrix product takes microseconds. torch's intra-op pool (one thread per core
by default) splits each such product across threads and spins while it waits for them: on an idle
machine that buys nothing, and on a loaded one the spinning threads fight every other process for
the cores (measured with ``benchmarks/bench_train.py --torch-threads``: docs/performance.md). So a
network below :data:`LARGE_NETWORK_PARAMS` trains on one thread; a larger one gets up to
:data:`MAX_THREADS`, never more than the cores this process may run on. ``OMP_NUM_THREADS`` in the
environment is the user's choice and is kept.
"""

from __future__ import annotations

import logging
import os
from typing import Any

_log = logging.getLogger(__name__)

#: parameters from which a network's matrix products are worth splitting across threads
LARGE_NETWORK_PARAMS = 1_000_000
MAX_THREADS = 4


def threads_for(parameters: int, cpus: int) -> int:
    """The torch threads for a network of ``parameters`` on ``cpus`` usable cores."""
    if parameters < LARGE_NETWORK_PARAMS:
        return 1
    return max(1, min(cpus, MAX_THREADS))


def usable_cpus() -> int:
    """The cores this process may run on (its affinity mask, e.g. a container's or taskset's)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def use_threads_for(network: Any) -> int:
    """Set torch's thread count for ``network`` (a torch module, e.g. an SB3 model's ``policy``)
    and return it; with ``OMP_NUM_THREADS`` set, keep torch's count (the user's choice)."""
    import torch

    if os.environ.get("OMP_NUM_THREADS"):
        return int(torch.get_num_threads())
    parameters = sum(int(p.numel()) for p in network.parameters())
    threads = threads_for(parameters, usable_cpus())
    torch.set_num_threads(threads)
    _log.info("torch threads: %d for a network of %s parameters", threads, f"{parameters:,}")
    return threads
