"""Safety value (the paper's eqs. safe_value), vectorised over vehicles.

``SV = clip(SV_d + SV_t + SV_acc, sv_min, sv_max)`` with

* ``SV_d = log((d / alpha_d) ** beta_d)`` computed as ``beta_d * log(d / alpha_d)``,
* ``SV_t = -(alpha_t / tanh(t)) ** beta_t`` for a time to collision ``0 < t < 1`` s, else 2
  (the paper prints ``tanh(-t)``; its sign is lost for the even default ``beta_t = 2`` and the
  magnitude is used so that any ``beta_t`` stays real),
* ``SV_acc = lambda_acc * acc * log(min(d_front / d_threshold, alpha_acc) ** beta_acc)``.

Every log and division is guarded: no vehicle (``d = inf``) is the safest case and gives
``sv_max``; a distance of 0 gives ``sv_min``; no front vehicle gives ``SV_acc = 0``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mivecc_env.config import MiVeCCConfig

#: Distances are floored at this value [m] before a log.
MIN_DISTANCE_M = 1e-6
#: A time to collision is floored at this value [s] before tanh.
MIN_TTC_S = 1e-6
#: SV_t outside the sensitive range (0, 1) s.
SV_T_SAFE = 2.0


def time_to_collision(gap_m: NDArray, closing_speed_mps: NDArray) -> NDArray:
    """Gap over closing speed [s]; ``inf`` when the two vehicles are not closing in."""
    closing = np.asarray(closing_speed_mps, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing > 0, gap_m / np.where(closing > 0, closing, 1.0), np.inf)
    return ttc


def safety_value(
    d_nearest_m: NDArray,
    ttc_s: NDArray,
    d_front_m: NDArray,
    acc_mps2: NDArray,
    config: MiVeCCConfig,
) -> NDArray:
    """Safety value of each vehicle.

    Args:
        d_nearest_m: distance to the nearest vehicle on the virtual lane [m] (``inf``: none).
        ttc_s: time to collision with that vehicle [s] (``inf``: not closing in).
        d_front_m: distance to the vehicle in front on the virtual lane [m] (``inf``: none).
        acc_mps2: acceleration used by SV_acc [m/s^2] (front vehicle's or the ego's, see
            ``config.sv_acc_source``); ignored (term 0) where there is no front vehicle.
        config: the model constants.

    Returns:
        SV in ``[config.sv_min, config.sv_max]``, never NaN.
    """
    c = config
    d = np.maximum(np.asarray(d_nearest_m, dtype=np.float64), MIN_DISTANCE_M)
    if c.sv_d_epsilon > 0.0:  # released code: ln((d / alpha)^beta + eps), floored
        with np.errstate(over="ignore"):
            sv_d = np.log((d / c.sv_alpha_d) ** c.sv_beta_d + c.sv_d_epsilon)
    else:
        sv_d = c.sv_beta_d * np.log(d / c.sv_alpha_d)

    ttc = np.asarray(ttc_s, dtype=np.float64)
    sensitive = (ttc > 0.0) & (ttc < 1.0)
    sv_t = np.full(ttc.shape, SV_T_SAFE)
    if sensitive.any():  # tanh and the power only where 0 < TTC < 1 s (few vehicles)
        t = np.maximum(ttc[sensitive], MIN_TTC_S)
        sv_t[sensitive] = -((c.sv_alpha_t / np.tanh(t)) ** c.sv_beta_t)

    d_front = np.maximum(np.asarray(d_front_m, dtype=np.float64), MIN_DISTANCE_M)
    if c.sv_no_front_distance_m is not None:  # released code: nothing ahead counts as 100 m
        d_front = np.where(np.isfinite(d_front), d_front, c.sv_no_front_distance_m)
    has_front = np.isfinite(d_front)
    ratio = np.minimum(d_front / c.sv_d_threshold_m, c.sv_alpha_acc)
    if c.sv_acc_epsilon > 0.0:  # released code: ln(ratio^beta + eps)
        log_term = np.log(ratio**c.sv_beta_acc + c.sv_acc_epsilon)
    else:
        log_term = c.sv_beta_acc * np.log(ratio)
    sv_acc = np.where(has_front, c.sv_lambda_acc * acc_mps2 * log_term, 0.0)
    return np.clip(sv_d + sv_t + sv_acc, c.sv_min, c.sv_max)
