"""The collector class each Ray worker of :func:`mivecc_agents.collectors.make_collector` runs.

Ray names an actor's log lines after the actor's ``repr``; a worker prints that ``repr`` when it
starts, and Ray prints every line of it past the first to the driver as if the worker had
logged it. TorchRL's ``Collector`` ``repr`` spans about 40 lines (its env, policy and buffer),
so every Ray run printed it, twice. This subclass only shortens the ``repr``.
"""

from __future__ import annotations

from torchrl.collectors import Collector

__all__ = ["RayWorkerCollector"]


class RayWorkerCollector(Collector):
    """TorchRL's ``Collector`` with a one-line ``repr`` (the prefix of its Ray log lines)."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"
