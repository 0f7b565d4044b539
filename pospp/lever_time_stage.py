"""The joint estimate of the lever arm and the GNSS time offset on a flight: the stage
functions over A's lever-arm pass (:func:`pospp.flight_stages.lever_arm_passes`) on the log
re-stamped (:func:`pospp.diagnose.rerun.restamped`) that :mod:`pospp.qc.lever_time` profiles.
The QC stage, compare-sim and the diagnosis's sensor families read :func:`lever_time_estimate`
(one per run, shared).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from pospp.config import PipelineConfig
from pospp.diagnose.rerun import restamped
from pospp.flight_stages import QC_LEVER_ARM_SIGMA_M, lever_arm_passes, lever_arm_seen, navigate
from pospp.io import mcap_reader
from pospp.nav import filter as nav_filter
from pospp.qc.lever_time import LeverPass, LeverTime, lever_pass, lever_time_joint

__all__ = ["lever_time_estimate", "lever_time_pass", "qc_passes"]


LEVER_TIME_GATE_PROBABILITY = 1.0 - 1e-9
"""The gate of :func:`lever_time_pass` (NIS 47 at 3 dof): a gate that drops records at one trial
offset and keeps them at the next makes the profile's sum of NIS jump."""


def lever_time_pass(log: mcap_reader.FlightLog, seen: np.ndarray, config: PipelineConfig,
                    shift_s: float, start_b_m: Any) -> LeverPass:
    """One forward pass of A with lever-arm states (as :func:`lever_arm_passes`, one pass,
    the revealed axes ``seen`` from ``start_b_m``, the others at the configured value, the
    gate at :data:`LEVER_TIME_GATE_PROBABILITY`) on the log re-stamped by ``shift_s``
    (:func:`restamped`), keeping its gains (their innovation covariances whiten the
    innovations of :func:`pospp.qc.lever_time.innovation_lrv_ratio`):
    :func:`pospp.qc.lever_time.lever_pass`. ValueError when A fails."""
    rerun = replace(config, gnss=replace(config.gnss, estimate_lever_arm=True))
    opts = replace(config.filter_options(), smoother=False, lever_arm_sigma_m=QC_LEVER_ARM_SIGMA_M,
                   gate_probability=LEVER_TIME_GATE_PROBABILITY)
    start = np.where(np.asarray(seen, dtype=bool), np.asarray(start_b_m, dtype=float),
                     np.asarray(config.gnss.lever_arm_m, dtype=float))
    return lever_pass(navigate(restamped(log, shift_s), rerun, lever_arm_b_m=start,
                               options=opts, record_gains=True), shift_s)


def lever_time_estimate(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult,
                        config: PipelineConfig,
                        lever: nav_filter.LeverArmEstimate | None = None) -> LeverTime | None:
    """The lever arm and the GNSS time offset estimated jointly
    (:func:`pospp.qc.lever_time.lever_time_joint` over :func:`lever_time_pass`, the first
    pass started from ``lever``, A's lever-arm estimate, made when None); None when A fails
    or estimates the lever arm itself."""
    if config.gnss.estimate_lever_arm:
        return None
    seen = lever_arm_seen(nav)
    try:
        lever = lever if lever is not None else lever_arm_passes(log, seen, config)
    except ValueError:
        return None
    return lever_time_joint(lambda s, start: lever_time_pass(log, seen, config, s, start),
                            np.asarray(config.gnss.lever_arm_m, dtype=float),
                            np.asarray(lever.lever_b_m, dtype=float),
                            grid_s=float(np.median(np.diff(log.imu.time_ns))) * 1e-9)


def qc_passes(log: mcap_reader.FlightLog, nav: nav_filter.FilterResult, config: PipelineConfig,
              lever: nav_filter.LeverArmEstimate | None,
              joint: Callable[[], LeverTime | None] | None = None) -> dict[str, Any]:
    """The QC stage's passes of A that it makes only when a check needs them
    (:func:`pospp.qc.stage.quality_checks`'s ``joint`` and ``renavigate``): the joint
    estimate (``joint``, when another stage shares it; else made from A's lever-arm
    estimate ``lever``), and A on the log re-stamped."""
    return {"joint": joint or (lambda: lever_time_estimate(log, nav, config, lever)),
            "renavigate": lambda shift_s: navigate(restamped(log, shift_s), config)}

