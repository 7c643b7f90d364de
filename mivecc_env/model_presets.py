"""Named model presets: the config fields that the ``model`` field sets.

``model="paper"`` is this project's reading of the paper's text (the defaults);
``model="released"`` sets every behaviour of the authors' released simulator
(``docs/model.md``, divergence table), each as its own field so that any one can be switched
back alone.

Precedence (tested in ``tests/sim/test_released.py``):

* ``MiVeCCConfig(model="released", v_min_mps=6.0)``: the preset, then the explicit keywords
  (``v_min_mps`` stays 6);
* ``from_overrides(base, model="released", ...)`` / ``config.replace(model="released", ...)``
  / ``parallel_env(model="released", ...)`` / ``mivecc evaluate --set model=released ...``: the
  base config, then the preset, then the other explicit overrides;
* a replace that does not name ``model`` keeps every field of the base config.

``model`` therefore records which preset was applied last; explicit overrides may change
preset fields afterwards.
"""

from __future__ import annotations

from typing import Any

#: Behaviours of the released code (units in the field names).
RELEASED: dict[str, Any] = {
    "v_min_mps": 5.0,  # 7: velocity range [5, 13]
    "entry_clearance_m": 0.0,  # 7: no entry clearance check
    "entry_accel_mps2": 3.0,  # 7: a new vehicle enters with a = +a_max
    "speed_reset": True,  # 1
    "stale_action": True,  # 1/3: out of the virtual lanes, a vehicle acts on its last a_end
    "stale_corner_reset": True,  # 1c: the debug branch of the released code's section 8
    "sections": True,  # 2
    "section_virtual_lanes": True,  # 3
    "section_entry_lag": True,  # 3: one step unseen after entering the network or a section
    "header_rule": True,  # 4
    "sv_d_epsilon": 1e-4,  # 5
    "sv_acc_epsilon": 1e-7,  # 5
    "sv_no_front_distance_m": 100.0,  # 5
    "ttc_closing_offset_mps": 0.1,  # 5
    "accel_record": "commanded",  # 5: SV_acc sees the commanded a when a bound cut the step
    "same_lane_rule": True,  # 6
    "same_lane_rule_form": "released",  # 6
    "edge_sv_gate": -2.0,  # 8
    "edge_selection": "random",  # 8 (test time; the released training picks the lowest SV)
    "reward_sv_weight": 1.0,  # edge reward: mean SV with weight 1
    "edge_reward_scope": "decisions",  # ... + mean (v - 12) of the selected vehicles
    "cloud_pick_population": "before_last_centre",  # 9: cloud picks before the last centre
    "cloud_view": "released",  # 9: each crossing lane's whole upstream part on the cloud's lanes
    "cloud_reward_population": "released",  # 9: cloud reward over the controlled vehicles
}

#: The same fields at this project's defaults (the paper reading).
PAPER: dict[str, Any] = {
    "v_min_mps": 6.0,
    "entry_clearance_m": 10.0,
    "entry_accel_mps2": 0.0,
    "speed_reset": False,
    "stale_action": False,
    "stale_corner_reset": False,
    "sections": False,
    "section_virtual_lanes": False,
    "section_entry_lag": False,
    "header_rule": False,
    "sv_d_epsilon": 0.0,
    "sv_acc_epsilon": 0.0,
    "sv_no_front_distance_m": None,
    "ttc_closing_offset_mps": 0.0,
    "accel_record": "applied",
    "same_lane_rule": False,
    "same_lane_rule_form": "project",
    "edge_sv_gate": None,
    "edge_selection": "lowest_sv",
    "reward_sv_weight": 0.05,
    "edge_reward_scope": "area",
    "cloud_pick_population": "conflict_ahead",
    "cloud_view": "window",
    "cloud_reward_population": "picks",
}

MODEL_PRESETS: dict[str, dict[str, Any]] = {"paper": PAPER, "released": RELEASED}
