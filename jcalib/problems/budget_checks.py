"""Stated σ tested against the data: every stated noise level, prior and assumption.

- **noise levels** (corner, tip, axis, contact, pose measurement σ): the kind's χ² against its *stated* σ
  over its redundancy (``Σ_g χ²_g · s_k / Σ_g (m_g − tr(H_g H⁻¹))``, ``s_k`` the variance component the
  solve applied), taken after the stated inputs moved to where the data put them within their stated σ
  (a held camera that is off by its stated σ makes the corners worse than their noise: that is not the
  noise's fault);
- **robot pose noise** (``pose_noise``): the flange corrections' χ² against the stated σ over their
  redundancy (:func:`jcalib.problems.assemble.robot_statistics`); a kinematic calibration's repeatability
  likewise (the ``kinematic:<robot>`` residuals);
- **assumptions** (a target's scale, held intrinsics and transforms, held kinematic parameters): a score
  test. With ``M`` the marginal information of the stated inputs given the data and ``g = ∂C/∂θ`` at the
  solution (:func:`jcalib.solve.sensitivity.sensitivities`), the data's correction ``δ = −M⁻¹ g`` has
  covariance ``f·M⁻¹ + Σ_θ`` if the stated value and σ are right (``f`` the variance factor); its χ² is
  taken over the directions the data determine to within :data:`TESTABLE_RATIO` stated σ.

A stated σ is **contradicted** when its χ² is beyond the ``1 − ALPHA`` quantile of its χ² law *and*
its factor (``√(χ²/dof)``, how many times the stated σ the data show) is beyond :data:`FACTOR`: a
statistically sure and practically large disagreement. Worse than stated is a warning; better than stated
is a note (the stated σ is pessimistic).
"""

from __future__ import annotations

import numpy as np
from scipy import stats as st

#: Significance of a check (one-sided).
ALPHA = 1e-3
#: Practical threshold: a stated σ is contradicted only when the data show at least this factor more (or
#: this factor less).
FACTOR = 1.5
#: An assumption's direction is tested only where the data determine it within this many stated σ.
TESTABLE_RATIO = 10.0


def _verdict(chi2: float, dof: float) -> tuple[float, float, str]:
    if not dof > 0 or not np.isfinite(chi2):
        return float("nan"), float("nan"), "not testable"
    factor = float(np.sqrt(chi2 / dof))
    high, low = float(st.chi2.sf(chi2, dof)), float(st.chi2.cdf(chi2, dof))
    if high < ALPHA and factor > FACTOR:
        return factor, high, "worse than stated"
    if low < ALPHA and factor < 1.0 / FACTOR:
        return factor, low, "better than stated"
    return factor, min(high, low), "consistent"


def _entry(what, kind, stated, chi2, dof, message_worse, message_better=None, **extra) -> dict:
    factor, p, verdict = _verdict(float(chi2), float(dof))
    def num(x):
        return float(x) if np.isfinite(x) else None

    out = {"what": what, "kind": kind, "stated": stated, "factor": num(factor), "chi2": num(chi2), "dof": num(dof),
           "p_value": num(p), "verdict": verdict, **extra}
    if verdict == "worse than stated":
        out["message"] = message_worse.format(factor=factor)
    elif verdict == "better than stated":
        out["message"] = (message_better or "{what}: the data show {factor:.2f}x the stated σ; the stated σ is "
                          "pessimistic").format(factor=factor, what=what)
    return out


_UNITS = {"corner": ("px", 1.0), "corner_mean": ("px", 1.0), "tip": ("px", 1.0), "axis": ("px", 1.0),
          "contact": ("mm", 1e3), "pose_rotation": ("deg", float(np.degrees(1.0))), "pose_translation": ("mm", 1e3)}


def noise_checks(built, r, sens=None) -> list[dict]:
    """Each residual kind's χ² against its stated σ. With stated inputs (``sens.chi2``), the χ² is taken after
    the inputs moved to where the data put them within their stated σ: residuals that a held input explains
    (within what was stated for it) are not charged to the noise."""
    sol = r.sol
    moved = sens.chi2 if sens is not None else {}
    total_m = max(sol.num_residuals, 1)
    share = max(1.0 - sol.num_free / total_m, 0.0)
    out = []
    for kind in sorted({gr.kind for gr in built.groups}):
        scale = r.components.get(kind, 1.0) if r.components else 1.0
        chi2 = dof = 0.0
        for gr in built.groups:
            if gr.kind != kind:
                continue
            hat = sol.hat.get(gr.name, float("nan"))
            change = moved[gr.name][1] - moved[gr.name][0] if gr.name in moved else 0.0
            chi2 += max(sol.chi2[gr.name] + change, 0.0) * scale
            dof += sol.count[gr.name] - hat if np.isfinite(hat) else sol.count[gr.name] * share
        unit, k = _UNITS.get(kind, ("", 1.0))
        sigma = built.sigma[kind] * k
        out.append(_entry(f"{kind} noise", "noise", f"{sigma:.4g} {unit}", chi2, dof,
                          f"{kind} residuals are {{factor:.1f}}x the stated {kind} noise ({sigma:.4g} {unit}): the "
                          "detections, the lens model or the stated σ is worse than stated"))
    return out


def robot_checks(g, built, r, cal) -> list[dict]:
    out = []
    for rb, s in cal.robot.items():
        red = float(s.get("redundancy", float("nan")))
        prior_t = np.asarray(s["prior_sigma_translation_m"], np.float64)
        post_t = np.asarray(s["a_posteriori_sigma_translation_m"], np.float64)
        factor = float(np.max(post_t / prior_t)) if np.all(prior_t > 0) else float("nan")
        rms = np.asarray(s["correction_rms_translation_m"]) * 1e3
        stated = " / ".join(f"{v * 1e3:.3g}" for v in np.atleast_1d(prior_t)) + " mm"
        out.append(_entry(f"{g.label(rb)} pose noise", "robot", stated, factor**2 * red, red,
                          f"flange corrections {' / '.join(f'{v:.3g}' for v in rms)} mm RMS (x / y / z) against a "
                          f"stated pose noise of {stated} ({{factor:.1f}}x): the robot, its time sync or its pose "
                          "recording is worse than stated", robot=rb))
    sol = r.sol
    for rb in built.kinematics:
        name = f"kinematic:{rb}"
        hat = sol.hat.get(name, float("nan"))
        if name in sol.chi2 and np.isfinite(hat):
            rep = cal.kinematics[rb]["repeatability"]
            stated = " / ".join(f"{v * 1e3:.3g}" for v in rep["translation_m"]) + " mm"
            out.append(_entry(f"{g.label(rb)} repeatability", "robot", stated, sol.chi2[name],
                              sol.count[name] - hat,
                              f"{g.label(rb)}'s flange poses scatter {{factor:.1f}}x its stated repeatability "
                              f"({stated}) about the calibrated kinematics: the robot, its time sync or its pose "
                              "recording is worse than stated, or its kinematic model misses an error", robot=rb))
    return out


def score_checks(items, sens, f0: float) -> list[dict]:
    out = []
    for it in items:
        if it.kind == "noise" or sens is None:
            continue
        sl = slice(it.start, it.start + it.size)
        M = sens.information[sl, sl]
        g = sens.score[sl]
        w, U = np.linalg.eigh(0.5 * (it.cov + it.cov.T))
        keep = w > max(float(np.max(w)), 0.0) * 1e-12
        L = U[:, keep] * np.sqrt(w[keep])  # Σ = L Lᵀ
        Mu, gu = L.T @ M @ L, L.T @ g
        lam, V = np.linalg.eigh(0.5 * (Mu + Mu.T))
        ok = lam > f0 / TESTABLE_RATIO**2
        d = -(V[:, ok].T @ gu) / lam[ok]
        chi2 = float(np.sum(d**2 / (f0 / lam[ok] + 1.0)))
        dof = int(ok.sum())
        entry = _entry(it.key, "assumption", it.sigma_text, chi2, dof,
                       f"{it.what}: the data put it {{factor:.1f}}x its stated σ ({it.sigma_text}) away from the "
                       f"stated value: {it.advice}")
        if dof == 0:
            entry["note"] = "these data cannot tell (they do not determine it within 10x its stated σ)"
        out.append(entry)
    return out


def assumption_checks(g, built, r, cal, items, sens) -> list[dict]:
    """Every stated σ against the data (see the module docstring): a list of
    ``{what, kind, stated, factor, chi2, dof, p_value, verdict[, message]}``."""
    f0 = float(r.sol.sigma2) if r.cov_noise == "a_posteriori" and r.sol.sigma2 == r.sol.sigma2 else 1.0
    return noise_checks(built, r, sens) + robot_checks(g, built, r, cal) + score_checks(items, sens, f0)
