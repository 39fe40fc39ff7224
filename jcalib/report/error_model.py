"""The robot error model a calibration used (``stats.robot_error_model``, :mod:`jcalib.problems.error_model`):
one console line and a report section with every model's held-out score."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from jcalib.report.markup import esc, fmt, note, table

__all__ = ["error_model_line", "error_model_section"]


def _chosen(info: Mapping[str, Any]) -> str:
    chosen = info.get("robots", info.get("chosen"))
    return ", ".join(f"{r}: {m}" for r, m in chosen.items()) if isinstance(chosen, dict) else str(chosen)


def _level(info: Mapping[str, Any]) -> str:
    level = info.get("pose_noise_level") or {}
    return "; ".join(f"estimated pose error {v['translation_m'] * 1e3:.3g} mm / {v['rotation_deg']:.3g}° per axis "
                     f"(prior {v['prior_translation_m'] * 1e3:.3g} mm / {v['prior_rotation_deg']:.3g}°)"
                     for v in level.values())


def error_model_line(stats: Mapping[str, Any]) -> str | None:
    """``"robot error model: pose_noise (held-out px: exact 2.48, pose_noise 2.44 ...)"``, or None."""
    info = stats.get("robot_error_model")
    if not info:
        return None
    scores = info.get("scores") or {}
    text = f"robot error model: {_chosen(info)}"
    if scores:
        text += " (chosen by held-out prediction, px RMS: " + ", ".join(
            f"{m} {s['rms_px']:.3f}" if s.get("rms_px") is not None else f"{m} –" for m, s in scores.items()) + ")"
    else:
        text += f" ({info.get('criterion', '')})"
    level = _level(info)
    return text + (f"; {level}" if level else "")


def error_model_section(stats: Mapping[str, Any]) -> str:
    """The report section: the chosen model, why, and each compared model's held-out error and corner σ."""
    info = stats.get("robot_error_model")
    if not info:
        return ""
    head = "<h3>Robot error model</h3>"
    text = f"Robot error model: {_chosen(info)} ({info.get('criterion', '')})."
    level = _level(info)
    if level:
        text += f" Pose model: {level}."
    for m, why in (info.get("not_applicable") or {}).items():
        text += f" {m}: not applicable ({why})."
    for m, why in (info.get("failed") or {}).items():
        text += f" {m}: failed ({why})."
    rows = [[esc(m), fmt(s.get("rms_px"), 3) if s.get("rms_px") is not None else "–", fmt(s.get("sigma_px"), 3)]
            for m, s in (info.get("scores") or {}).items()]
    out = head + note(esc(text))
    if rows:
        out += table(["model", "held-out RMS (px per point)", "a-posteriori corner σ (px)"], rows, {1, 2})
    return out
