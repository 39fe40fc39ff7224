"""Estimators of a study: the one builder with options, and closed-form baselines.

- **Builder** estimators (``joint``, ``joint_pose_model``, or ``{name, options}``) are
  :func:`jcalib.calibrate_batch` on the trials of a batch: one call per estimator, the solves and every
  refinement round vmapped over the trials of one structure. Their options are the
  :class:`~jcalib.problems.options.CalibrationOptions` fields the scenario gives, plus the simulated
  noise as the stated σ of each measurement kind the station blocks produce (``sigma_px``,
  ``tip_sigma_px``, ``axis_sigma_px``, ``contact_sigma_m``, ``pose_sigma_deg`` / ``pose_sigma_m``;
  floored at 1e-3 px, 1e-7 m, 1e-5 deg) unless the estimator sets them.
- **Closed forms** (:mod:`jcalib.study.closed_forms`) run trial by trial and report no covariance
  unless their method has one (the analytic TCP and pivot methods).

``runtime_s`` is the wall time of the estimator alone (simulation not counted): for a builder
estimator the batch's time divided by its size (the first call of a process includes JAX's
compilation), for a closed form its own time.
"""

from __future__ import annotations

import time

from jcalib.errors import JcalibError
from jcalib.study.closed_forms import closed_form
from jcalib.study.estimate import Estimate, from_calibration
from jcalib.study.scenario import Estimator, Scenario
from jcalib.study.simulate import Trial

__all__ = ["Estimate", "builder_options", "run_estimator"]


def _kinds(scenario: Scenario) -> set[str]:
    """Measurement kinds the scenario's station blocks produce."""
    kinds = set()
    for b in scenario.stations:
        if b.kind == "pair":
            kinds.add("poses" if b.measure == "poses" else "corners")
        elif b.kind == "tcp":
            kinds.add("tips")
            if b.options.get("axis_points"):
                kinds.add("axis")
        elif b.kind == "pivot":
            kinds.add("contacts")
        else:
            if scenario.cell_spec.targets:
                kinds.add("corners")
            if any(rec.get("contacts") for rec in b.stations):
                kinds.add("contacts")
    return kinds


def builder_options(scenario: Scenario, estimator: Estimator) -> dict:
    """The estimator's options with the simulated noise as the stated σ (see the module docstring)."""
    n = scenario.noise
    kinds = _kinds(scenario)
    stated = {}
    if "corners" in kinds:
        stated["sigma_px"] = max(n.pixel_sigma_px, 1e-3)
    if "tips" in kinds:
        stated["tip_sigma_px"] = max(n.tip_px, 1e-3)
    if "axis" in kinds:
        stated["axis_sigma_px"] = max(n.axis_sigma_px, 1e-3)
    if "contacts" in kinds:
        stated["contact_sigma_m"] = max(n.contact_sigma_m, 1e-7)
    if "poses" in kinds:
        stated["pose_sigma_deg"] = max(n.pose_rotation_deg, 1e-5)
        stated["pose_sigma_m"] = max(n.pose_translation_m, 1e-7)
    return {**stated, **estimator.options}


def _builder(scenario: Scenario, estimator: Estimator, trials: list[Trial]) -> list[Estimate | Exception]:
    from jcalib.problems.batch import calibrate_batch
    from jcalib.problems.calibrate import calibrate_cell, options_and_given

    options = builder_options(scenario, estimator)
    t0 = time.perf_counter()
    try:
        results: list = calibrate_batch([t.cell for t in trials], [t.observations for t in trials], options)
    except JcalibError as err:  # options refused for every trial alike
        results = [err] * len(trials)
    except Exception:  # noqa: BLE001  (the batched solve itself failed: find the trials one by one)
        opts, given = options_and_given(options)
        results = []
        for t in trials:
            try:
                results.append(calibrate_cell(t.cell, t.observations, opts, given=given))
            except Exception as err:  # noqa: BLE001  (a failed trial is a row, not a crash)
                results.append(err)
    dt = (time.perf_counter() - t0) / max(len(trials), 1)
    out: list[Estimate | Exception] = []
    for r in results:
        if isinstance(r, Exception):
            out.append(r)
            continue
        est = from_calibration(r)
        est.runtime_s = dt
        out.append(est)
    return out


def run_estimator(scenario: Scenario, estimator: Estimator, trials: list[Trial]) -> list[Estimate | Exception]:
    """One estimator on a batch of trials: an :class:`Estimate` or the error, per trial."""
    if estimator.closed_form is None:
        return _builder(scenario, estimator, trials) if trials else []
    out: list[Estimate | Exception] = []
    for t in trials:
        t0 = time.perf_counter()
        try:
            est = closed_form(estimator.closed_form, scenario, t)
            est.runtime_s = time.perf_counter() - t0
            out.append(est)
        except Exception as err:  # noqa: BLE001  (a failed trial is a row, not a crash)
            err.runtime_s = time.perf_counter() - t0  # type: ignore[attr-defined]
            out.append(err)
    return out
