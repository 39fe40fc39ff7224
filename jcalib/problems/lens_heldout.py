"""The held-out-settings check of a zoom lens: leave the stations of some lens settings out of the fit,
predict the camera there from the lens functions, and compare with those stations' images.

Like the kinematics' held-out stations: the calibration is run again without the stations taken at the
held-out settings; each held-out station's target corners are then predicted from its recorded robot pose,
the camera's intrinsics and pose at the station's setting (the lens functions between the calibrated
settings) and the target's pose, and compared with the detected pixels. An RMS near the fit's own says
the functions interpolate the lens; far above it says the spline is too stiff (raise ``knots``) or the
settings too sparse.
"""

from __future__ import annotations

from dataclasses import replace

import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.cameras import camera_model_from_name
from jcalib.io.cell import CellSpec, load_cell
from jcalib.io.observations import Observations, load_observations
from jcalib.problems.calibrate import calibrate_cell
from jcalib.problems.lens import lens_function, setting_groups


def heldout_settings(cell: CellSpec | str | dict, obs: Observations | str | dict, held_out, options=None,
                     camera: str | None = None) -> dict:
    """Calibrate without the stations at the settings ``held_out`` and predict them.

    Args:
        cell, obs: the cell spec and observations (paths, dicts or parsed).
        held_out: lens setting values (of the camera's one setting) to leave out, with the stations whose
            recorded value reads back within jitter of one (:func:`jcalib.problems.lens.setting_groups`);
            each must be inside the range of the other settings (a prediction, not an extrapolation).
        options: :class:`jcalib.problems.options.CalibrationOptions` of the fit.
        camera: the zoom camera (default: the cell's only camera with ``lens:``).

    Returns:
        ``{"camera", "setting", "fit_rms_px", "rms_px", "settings": {value: {"rms_px", "num_points",
        "num_stations"}}}``: per-point RMS (px) of the held-out corners' prediction errors.

    Raises:
        BadInputError: no zoom camera, a held-out value no station has or outside the kept range, a camera
            and target that are not one on the flange and one fixed in the cell.
    """
    cell, obs = load_cell(cell), load_observations(obs)
    zooms = [c for c in cell.cameras.values() if c.lens is not None and (camera is None or c.name == camera)]
    if len(zooms) != 1:
        raise BadInputError(f"heldout_settings: expected one camera with lens: (or name it), got "
                            f"{[c.name for c in zooms] or 'none'}")
    cam = zooms[0]
    name = cam.lens.settings[0]
    held = sorted({float(v) for v in held_out})
    recorded = {st.id: st.lens.get(cam.name, {}).get(name) for st in obs.stations}
    group = setting_groups({v for v in recorded.values() if v is not None} | set(held))  # read-back jitter
    of_group = {group[h]: h for h in held}
    value = {sid: (None if v is None else of_group.get(group[v], v)) for sid, v in recorded.items()}
    kept = [st for st in obs.stations if value[st.id] not in held]
    out = [st for st in obs.stations if value[st.id] in held]
    missing = sorted(set(held) - {value[st.id] for st in out})
    if missing:
        raise BadInputError(f"heldout_settings: no station was taken at {name} = {missing}")
    rest = sorted({v for v in (recorded[st.id] for st in kept) if v is not None})
    outside = [v for v in held if not rest or not rest[0] < v < rest[-1]]
    if outside:
        raise BadInputError(f"heldout_settings: {name} = {outside} is not inside the kept settings' range "
                            f"[{rest[0] if rest else '-'}, {rest[-1] if rest else '-'}]; hold out inner settings")
    cal = calibrate_cell(cell, replace(obs, stations=tuple(kept)), options)
    entry = cal.lenses[cam.name]
    mount = entry["mount"]
    if mount is None or not (mount == f"T_flange_{cam.name}" or mount == f"T_base_{cam.name}"):
        raise BadInputError(f"heldout_settings: camera '{cam.name}' must be on the flange or fixed in the cell")
    lf = lens_function(entry, cal.transforms[mount])
    per: dict[float, list] = {v: [] for v in held}
    stations: dict[float, int] = dict.fromkeys(held, 0)
    for st in out:
        s = float(value[st.id])
        at = lf.at(float(recorded[st.id]))  # the camera at the station's own recorded setting
        model = camera_model_from_name(entry["model"], tuple(entry["image_size"]), at["params"])
        T_bf = st.T_base_flange
        for d in st.detections:
            if d.camera != cam.name or d.target is None:
                continue
            flange_cam, flange_t = mount.startswith("T_flange_"), f"T_flange_{d.target}" in cal.transforms
            if T_bf is None or flange_cam == flange_t:
                raise BadInputError(f"heldout_settings: station '{st.id}': camera '{cam.name}' and target "
                                    f"'{d.target}' must be one on the flange and one fixed in the cell, with a robot pose")
            W_cam = T_bf @ at["mount"] if flange_cam else at["mount"]
            W_t = cal.transforms[f"T_base_{d.target}"] if flange_cam else T_bf @ cal.transforms[f"T_flange_{d.target}"]
            T = np.linalg.inv(W_cam) @ W_t
            pts = np.asarray(obs.targets[d.target], np.float64)[np.asarray(d.point_index)]
            p = pts @ T[:3, :3].T + T[:3, 3]
            u = np.asarray(model.project(jnp.asarray(p)))
            per[s].append(np.sum((u - np.asarray(d.pixels)) ** 2, axis=1))
        stations[s] += 1
    settings = {}
    for s in held:
        sq = np.concatenate(per[s]) if per[s] else np.zeros(0)
        settings[s] = {"rms_px": float(np.sqrt(np.mean(sq))) if sq.size else float("nan"),
                       "num_points": int(sq.size), "num_stations": stations[s]}
    every = np.concatenate([np.concatenate(v) for v in per.values() if v]) if any(per.values()) else np.zeros(0)
    return {"camera": cam.name, "setting": name, "fit_rms_px": float(cal.rms_px),
            "rms_px": float(np.sqrt(np.mean(every))) if every.size else float("nan"), "settings": settings}


def with_heldout(file, check: dict):
    """The result file with a held-out-settings check (:func:`heldout_settings`) recorded under
    ``lenses.<cam>.heldout``, where the report marks the held-out settings and their prediction RMS."""
    from dataclasses import replace as dc_replace

    lenses = dict(file.extra.get("lenses") or {})
    cam = check["camera"]
    if cam not in lenses:
        raise BadInputError(f"with_heldout: the result has no lens functions for camera {cam!r}")
    def finite(x):
        return x if not isinstance(x, float) or np.isfinite(x) else None  # a result file holds no nan

    settings = {f"{float(s):g}": {k: finite(x) for k, x in v.items()} for s, v in check["settings"].items()}
    entry = {**lenses[cam], "heldout": {"fit_rms_px": finite(check["fit_rms_px"]), "rms_px": finite(check["rms_px"]),
                                        "settings": settings}}
    return dc_replace(file, extra={**file.extra, "lenses": {**lenses, cam: entry}})
