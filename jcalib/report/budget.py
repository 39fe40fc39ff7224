"""What limits a result: its error budget (sampling noise and each stated input) and the stated-σ checks.

Reads the result file only (``budget`` / ``covariance_combined`` per unknown, ``stats.assumptions``,
``stats.assumption_checks``, ``sensitivities``; :mod:`jcalib.problems.budget_file`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jcalib.io.result import ResultFile
from jcalib.report.markup import esc, note, table

#: An assumption is a "top contributor" on the console when its σ is at least this fraction of the
#: sampling σ of the same coordinate.
TOP_RATIO = 0.5
#: At most this many contributor lines on the console.
TOP_LINES = 5


def _entries(file: ResultFile) -> list[tuple[str, dict]]:
    out = []
    for section in (file.cameras, file.transforms, file.points, file.targets, file.kinematics):
        for name, entry in section.items():
            b = dict(entry.extra).get("budget")
            if isinstance(b, dict) and "sampling" in b:
                out.append((name, b))
    return out


def value_text(value: float, unit: str) -> str:
    """A σ in display units: rad -> deg, m -> mm."""
    if unit == "rad":
        return f"{np.degrees(value):.3g}°"
    if unit == "m":
        return f"{value * 1e3:.3g} mm"
    return f"{value:.3g}{' ' + unit if unit else ''}"


def contributors(file: ResultFile, ratio: float = TOP_RATIO, limit: int = TOP_LINES) -> list[dict]:
    """The coordinates where a stated input adds most against the sampling σ, largest ratio first:
    ``{unknown, coord, unit, sampling, key, sigma, ratio, what, advice}``."""
    what = {a["key"]: a for a in file.stats.get("assumptions") or []}
    rows = []
    for name, b in _entries(file):
        for i, coord in enumerate(b["coords"]):
            samp = float(b["sampling"][i])
            parts = {k: float(v[i]) for k, v in (b.get("assumptions") or {}).items()}
            if not parts:
                continue
            key = max(parts, key=parts.get)
            sig = parts[key]
            if sig <= 0 or (samp > 0 and sig < ratio * samp):
                continue
            rows.append({"unknown": name, "coord": coord, "unit": b["units"][i], "sampling": samp, "key": key,
                         "sigma": sig, "ratio": sig / samp if samp > 0 else float("inf"),
                         "what": what.get(key, {}).get("what", key), "advice": what.get(key, {}).get("advice", "")})
    rows.sort(key=lambda r: -r["ratio"])
    return rows[:limit]


def contributor_line(r: dict) -> str:
    """``"T_flange_cam0 tz: 0.08 mm from noise, 0.21 mm from board.square (...) — measure the board"``."""
    advice = f" — {r['advice']}" if r["advice"] else ""
    return (f"{r['unknown']} {r['coord']}: {value_text(r['sampling'], r['unit'])} from noise, "
            f"{value_text(r['sigma'], r['unit'])} from {r['key']} ({r['what']}){advice}")


def console_lines(file: ResultFile) -> list[str]:
    """The console's budget lines: the top contributors (or that none stands out) and the checks that the
    data contradict in the favourable direction (worse-than-stated ones are warnings already)."""
    if "assumptions" not in file.stats:
        return []
    lines = []
    top = contributors(file)
    stated = ", ".join(f"{a['key']} ({a['sigma']}, {a['source']})" for a in file.stats["assumptions"]) or "none"
    lines.append(f"error budget: stated inputs {stated}")
    if top:
        lines += [f"  what limits this result: {contributor_line(r)}" for r in top]
    elif file.stats["assumptions"]:
        lines.append(f"  every stated input adds less than {TOP_RATIO:.0%} of the sampling σ of every unknown")
    for c in file.stats.get("assumption_checks") or []:
        if c.get("verdict") == "better than stated":
            lines.append(f"  note: {c.get('message', c['what'])}")
    return lines


def section(file: ResultFile) -> str:
    """The report section "What limits this result" (every cell kind: with no stated input it says so)."""
    stats = file.stats
    out = ["<h2>What limits this result</h2>"]
    if "assumptions" not in stats:
        return out[0] + note("No error budget: the cell states no <code>assumptions:</code>, so every σ here is "
                             "sampling noise only (what the data's noise does to the estimate). State the inputs "
                             "that are taken as known, e.g. <code>assumptions: {board.square: {sigma_rel: "
                             "0.0005}}</code>, to see what each adds (guide: error budget).")
    out.append(note("Sampling σ (the covariance) is what the data's noise does to the estimate. Each stated input "
                    "(an assumption: a target's printed scale, held intrinsics or transforms, a robot's nominal "
                    "kinematics, a stated noise level) adds its own σ: sensitivity × stated σ, first order. "
                    "<b>combined</b> = sampling and every assumption (<code>covariance_combined</code>); the "
                    "sampling-only <code>covariance</code> is unchanged."))
    a_rows = [[esc(a["key"]), esc(a["what"]), esc(a["sigma"]), esc(a["source"])] for a in stats["assumptions"]]
    out.append(table(["input", "what", "stated σ", "source"], a_rows) if a_rows
               else note("No stated input: every σ is sampling noise only."))
    top = contributors(file, ratio=0.0, limit=12)
    if top:
        out.append("<h3>Largest contributions</h3>")
        out.append("<ul>" + "".join(f"<li>{esc(contributor_line(r))}</li>" for r in top) + "</ul>")
    rows = []
    for name, b in _entries(file):
        keys = list(b.get("assumptions") or {})
        for i, coord in enumerate(b["coords"]):
            if b["sampling"][i] == 0 and b["combined"][i] == 0:
                continue
            unit = b["units"][i]
            parts = "; ".join(f"{k} {value_text(float(b['assumptions'][k][i]), unit)}" for k in keys)
            rows.append([esc(name), esc(coord), esc(value_text(float(b["sampling"][i]), unit)), esc(parts),
                         esc(value_text(float(b["combined"][i]), unit))])
    if rows:
        out.append("<h3>Budget per unknown</h3>")
        out.append(table(["unknown", "coordinate", "sampling σ", "assumptions", "combined σ"], rows))
    checks = stats.get("assumption_checks") or []
    if checks:
        out.append("<h3>Stated σ against the data</h3>")
        out.append(note("Each stated noise level, prior and assumption tested against the solved residuals (χ² over "
                        "its kind, or a score test of the stated value); contradicted: beyond the 99.9 % quantile and "
                        "a factor 1.5 off."))
        out.append(table(["stated", "σ", "data / stated", "dof", "verdict"],
                         [[esc(c["what"]), esc(c["stated"]), _num(c.get("factor")), _num(c.get("dof"), 1),
                           esc(c.get("message", c["verdict"]))] for c in checks]))
    return "".join(out)


def _num(x: Any, digits: int = 2) -> str:
    return "–" if x is None else f"{float(x):.{digits}f}"


def sensitivity_rows(file: ResultFile, key: str, of: str | None = None) -> list[tuple[str, str, str, list[float]]]:
    """``(unknown, coordinate, unit, derivative per column)`` of every unknown w.r.t. the stated input ``key``
    (``sensitivities`` of the result). Raises BadInputError naming the inputs the result has."""
    from jcalib.errors import BadInputError

    sens = dict(file.extra).get("sensitivities") or {}
    if key not in sens:
        raise BadInputError(f"--wrt: the result has no sensitivities to {key!r}; it has: "
                            f"{', '.join(sorted(sens)) or 'none (state assumptions: in the cell and calibrate again)'}")
    rows = []
    for name, o in sens[key]["of"].items():
        if of is not None and name != of:
            continue
        units = next((b["units"] for n, b in _entries(file) if n == name), [""] * len(o["coords"]))
        for coord, unit, row in zip(o["coords"], units, o["jacobian"]):
            rows.append((name, coord, unit, [float(v) for v in row]))
    if of is not None and not rows:
        raise BadInputError(f"--of: no unknown {of!r} in the sensitivities; it has: {', '.join(sens[key]['of'])}")
    return rows
