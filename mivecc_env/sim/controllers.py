"""Dispatch of the planned control modes: which controller object a :class:`Simulator` owns.

``control="reservation"`` -> :class:`~mivecc_env.sim.reservation.ReservationControl`,
``control="optimisation"`` -> :class:`~mivecc_env.sim.optimisation.OptimisationControl`;
other modes have none (the simulator computes their accelerations itself). A controller has
``accel(sim, view, s, v) -> accelerations`` and ``reset()``.
"""

from __future__ import annotations

from typing import Any

from mivecc_env.config import MiVeCCConfig
from mivecc_env.sim.network import GridNetwork


def make_controller(config: MiVeCCConfig, network: GridNetwork, batch_size: int) -> Any:
    """The controller of ``config.control``, or None."""
    if config.control == "reservation":
        from mivecc_env.sim.reservation import ReservationControl

        return ReservationControl(config, network, batch_size)
    if config.control == "optimisation":
        from mivecc_env.sim.optimisation import OptimisationControl

        return OptimisationControl(config, network, batch_size)
    return None
