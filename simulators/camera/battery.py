"""A battery of varied simulated larvae: one rig configuration per seed, every realism feature on.

:func:`battery_config` is what ``benchmarks/make_battery.py`` writes sessions from, and what a test
uses to make one varied larva. The features and their ranges are those of ``config/simulated.yaml``
(documented in :mod:`vastcal.simulators.camera.larva` and :mod:`vastcal.simulators.camera.scene`); the battery only
switches them on, with these rates:
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from vastcal.config import RigConfig, SimulationConfig, load_config

BATTERY_SIMULATION: dict[str, Any] = {
    "larva_varies": True,
    "age_dpf": (3.0, 5.0),
    "fin_fold": True,
    "fin_fold_height_um": (60.0, 140.0),
    "pectoral_fins": True,
    "melanophores": 120.0,
    "wall_contact_probability": 0.4,
    "tail_out_of_frame_probability": 0.15,
    "pale_tail_tip_probability": 0.3,
    "wall_band_probability": 0.5,
    "debris": 3.0,
    "bubbles": 1.0,
    "illumination_gradient": 0.08,
    "vignetting": 0.15,
    "defocus_blur_px": (0.3, 1.2),
}
"""The ``simulation:`` keys the battery sets (over the base rig's)."""


def battery_config(seed: int, base: RigConfig | str | Path | None = None, **overrides: Any) -> RigConfig:
    """The rig of battery larva ``seed``: ``base`` (default ``config/simulated.yaml``) with
    :data:`BATTERY_SIMULATION` and ``simulation.seed = seed``; ``overrides`` replace any
    ``simulation`` key (e.g. ``fin_fold=False``). The larva, its features and the hidden rig pose
    are all drawn from ``seed``.
    """
    cfg = base if isinstance(base, RigConfig) else load_config(base)
    sim = cfg.simulation or SimulationConfig()
    fields = {f.name for f in dataclasses.fields(SimulationConfig)}
    unknown = set(overrides) - fields
    if unknown:
        raise TypeError(f"unknown simulation keys: {', '.join(sorted(unknown))}")
    sim = dataclasses.replace(sim, **{**BATTERY_SIMULATION, **overrides, "seed": int(seed)})
    return dataclasses.replace(cfg, simulation=sim, name=f"battery-{seed}")
