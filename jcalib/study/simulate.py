"""One simulated trial of a study: its truth, stations and observations, and the cell spec it is solved with.

Every random number of trial ``i`` comes from its own generator, derived from ``(seed, i)`` only
(:func:`trial_rng`), drawn in a fixed order: the truth (:func:`jcalib.study.truth.draw_truth`), the
stations (:func:`jcalib.study.stations.plan_stations`), then the measurements
(:func:`jcalib.sim.observe.simulate_observations`). A trial is therefore the same whichever batch or
worker runs it.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from jcalib.io.cell import CellSpec, parse_cell
from jcalib.io.observations import Observations, parse_observations
from jcalib.sim.observe import CellTruth, ObservationNoise, SimStation, simulate_observations
from jcalib.study.scenario import Scenario
from jcalib.study.stations import BlockRecord, holder, plan_stations
from jcalib.study.truth import draw_truth

__all__ = ["Trial", "observation_noise", "simulate_trial", "trial_cell", "trial_rng"]


def trial_rng(seed: int, trial: int) -> np.random.Generator:
    """The generator of trial ``trial`` of a study with ``seed``: ``SeedSequence(seed).spawn(...)[trial]``.

    Depends on ``(seed, trial)`` only, never on the batch or the worker that runs the trial.
    """
    return np.random.default_rng(np.random.SeedSequence(entropy=int(seed), spawn_key=(int(trial),)))


@dataclass
class Trial:
    """A simulated data set and what the estimators are given.

    Attributes:
        truth: the true cell.
        stations: the planned stations (true poses); ``records``: per station block, its station ids
            and what closed forms need (servo noise, goal pixel).
        observations: the simulated ``jcalib.observations/1`` data (parsed); ``kept``: ids of the
            stations that observed something.
        cell: the cell spec this trial is solved with (the scenario's, with the true values of the
            things it holds fixed or names in ``given``); ``cell_dict``: the same as plain data.
        num_planned: stations planned (before dropouts and stations without any detection).
    """

    truth: CellTruth
    stations: list[SimStation]
    records: list[BlockRecord]
    observations: Observations
    kept: list[str]
    cell: CellSpec
    cell_dict: dict
    num_planned: int


def observation_noise(scenario: Scenario) -> ObservationNoise:
    """The scenario's noise as the simulator takes it (robot noise per robot of the cell)."""
    n, cell = scenario.noise, scenario.cell_spec
    robots = dict(cell.robots) if cell.robots else ({(cell.robot.name or "robot"): cell.robot} if cell.robot else {})
    per_robot = {}
    for r, spec in robots.items():
        if n.robot_translation_m is not None:
            per_robot[r] = (np.full(3, n.robot_translation_m), np.full(3, n.robot_rotation_deg))
        elif spec is not None and spec.pose_noise_translation_m is not None:
            per_robot[r] = (np.asarray(spec.pose_noise_translation_m), np.asarray(spec.pose_noise_rotation_deg))
    return ObservationNoise(pixel_sigma_px=n.pixel_sigma_px, tip_sigma_px=n.tip_px, axis_sigma_px=n.axis_sigma_px,
                            robot=per_robot, pose_rotation_deg=n.pose_rotation_deg,
                            pose_translation_m=n.pose_translation_m, dropout_rate=n.dropout_rate,
                            min_points=n.min_points)


def trial_cell(scenario: Scenario, truth: CellTruth) -> dict:
    """The scenario's cell spec with the true values of what it holds fixed without a value, or ``given``.

    A camera whose every intrinsic is in ``fix`` (or named in ``given``) gets ``intrinsics`` (OpenCV K and
    dist of its true model); a fixed-mounted camera or target listed in ``fixed`` (or ``given``) gets its
    true ``pose``; a robot listed in ``fixed`` or ``given`` its true ``base``; a point its ``position``.
    """
    cell = copy.deepcopy(scenario.cell)
    spec = scenario.cell_spec
    given = set(scenario.given)
    fixed = set(spec.fixed)
    for c, cam in spec.cameras.items():
        entry = cell["cameras"][c]
        model = truth.cameras[c]
        names = set(model.param_names)
        if "intrinsics" not in entry and (c in given or names <= set(cam.fix)):
            K, dist = model.to_opencv()
            entry["intrinsics"] = {"K": np.asarray(K).tolist(), "dist": np.asarray(dist).ravel().tolist()}
        if "pose" not in entry and holder(spec, c) is None and (c in given or c in fixed):
            entry["pose"] = np.asarray(truth.poses[c]).tolist()
    for t, tgt in spec.targets.items():
        entry = cell["targets"][t]
        if "pose" not in entry and holder(spec, t) is None and (t in given or t in fixed):
            entry["pose"] = np.asarray(truth.poses[t]).tolist()
    for r in spec.robots:
        entry = cell["robots"].get(r) or {}
        if entry.get("base") is None and (r in given or r in fixed or f"T_world_{r}" in fixed) and r in truth.bases:
            entry["base"] = np.asarray(truth.bases[r]).tolist()
            cell["robots"][r] = entry
    for p in spec.points:
        entry = (cell.get("points") or {}).get(p) or {}
        if "position" not in entry and (p in given or p in fixed):
            entry["position"] = np.asarray(truth.points[p]).tolist()
            cell["points"][p] = entry
    return cell


def simulate_trial(scenario: Scenario, seed: int, trial: int) -> Trial:
    """The data of trial ``trial`` (see the module docstring).

    Raises:
        BadInputError: the scenario cannot be simulated (e.g. a target too large for the image).
    """
    rng = trial_rng(seed, trial)
    spec = scenario.cell_spec
    truth = draw_truth(spec, scenario.truth, rng)
    noise = observation_noise(scenario)
    stations, records = plan_stations(spec, truth, scenario.stations, scenario.noise, rng)
    obs, kept = simulate_observations(spec, truth, stations, noise, rng)
    cell_dict = trial_cell(scenario, truth)
    return Trial(truth=truth, stations=stations, records=records, observations=parse_observations(obs), kept=kept,
                 cell=parse_cell(cell_dict, source=scenario.cell_spec.source), cell_dict=cell_dict,
                 num_planned=len(stations))
