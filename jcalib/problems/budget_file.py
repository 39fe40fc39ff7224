"""The error budget in the result file (``jcalib.result/1``, optional keys).

Per unknown (camera, transform, point, target warp, robot kinematics), beside the sampling-only
``covariance`` that stays as it is:

- ``budget``: ``{"coords", "sampling" (σ per coordinate), "assumptions": {key: σ per coordinate},
  "combined"}`` (the unknown's own units: px, rad, m);
- ``covariance_combined``: sampling + every assumption's ``S Σ Sᵀ``, same shape and order as ``covariance``.

Top level: ``sensitivities``: assumption key -> ``{"what", "columns", "units", "of": {unknown: {"coords",
"jacobian" (d x p)}}}`` (derivative of the unknown's coordinates per unit of each column: a user can
re-scale with another σ). ``stats.assumptions`` lists the assumptions (stated or default) and
``stats.assumption_checks`` each stated σ tested against the data.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jcalib.io.result import ResultFile


def _budget_entry(u: dict) -> dict:
    return {"budget": {"coords": list(u["coords"]), "units": list(u["units"]),
                       "sampling": np.asarray(u["sampling"]).tolist(),
                       "assumptions": {k: np.asarray(v).tolist() for k, v in u["contributions"].items()},
                       "combined": np.asarray(u["combined"]).tolist()},
            "covariance_combined": np.asarray(u["covariance_combined"]).tolist()}


def attach(file: ResultFile, budget: dict | None) -> ResultFile:
    """``file`` with the budget's keys (see the module docstring); unchanged when ``budget`` is None."""
    if not budget:
        return file
    units = budget["unknowns"]
    sections = {"camera": "cameras", "transform": "transforms", "point": "points", "target": "targets",
                "kinematics": "kinematics"}
    changes: dict[str, dict] = {v: dict(getattr(file, v)) for v in sections.values()}
    for label, u in units.items():
        section = changes[sections[u["kind"]]]
        if label in section:
            entry = section[label]
            section[label] = dataclasses.replace(entry, extra={**dict(entry.extra), **_budget_entry(u)})
    stats = dict(file.stats)
    stats["assumptions"] = budget["assumptions"]
    stats["assumption_checks"] = budget["checks"]
    warnings = list(stats.get("warnings", []))
    warnings += [c["message"] for c in budget["checks"] if c["verdict"] == "worse than stated"]
    if warnings:
        stats["warnings"] = warnings
    notes = list(stats.get("notes", [])) + list(budget["notes"])
    if notes:
        stats["notes"] = notes
    sens = {k: {"what": s["what"], "columns": list(s["columns"]), "units": list(s["units"]),
                "of": {n: {"coords": list(o["coords"]), "jacobian": np.asarray(o["jacobian"]).tolist()}
                       for n, o in s["of"].items()}}
            for k, s in budget["sensitivities"].items()}
    extra = {**dict(file.extra), "sensitivities": sens}
    return dataclasses.replace(file, stats=stats, extra=extra, **changes)
