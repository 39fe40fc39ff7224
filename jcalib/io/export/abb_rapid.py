"""Export TCPs and work objects as ABB RAPID ``tooldata`` / ``wobjdata`` in a RAPID module.

``tooldata`` (a tool held by the robot, from ``T_flange_<tool>``; ``flange`` = ABB's ``tool0``)::

    PERS tooldata tool_needle := [TRUE, [[x, y, z], [q1, q2, q3, q4]],
                                  [mass, [cogx, cogy, cogz], [1, 0, 0, 0], ix, iy, iz]];

``robhold = TRUE``; ``tframe`` = the TCP in the flange frame: ``x, y, z`` in mm (3 decimals,
0.001 mm) and the unit quaternion ``q1..q4 = w, x, y, z`` with ``q1 >= 0`` (6 decimals, about
1e-6 rad; RAPID ``num`` is single precision, so more digits carry nothing). ``tload`` is the load
data: the calibration does not measure it, and RAPID rejects a tool with mass 0, so unless given
(:class:`ToolLoad`) it is :data:`DEFAULT_TOOL_LOAD`: **1 kg at the TCP**, axes of moment
``[1, 0, 0, 0]``, zero inertia. Identify the real load (``LoadIdentify``) before production.

``wobjdata`` (a fixed work object, from ``T_base_<wobj>``)::

    PERS wobjdata wobj_board := [FALSE, TRUE, "", [[x, y, z], [q1, q2, q3, q4]], [[0, 0, 0], [1, 0, 0, 0]]];

``robhold = FALSE``, ``ufprog = TRUE``, ``ufmec = ""``, ``uframe`` = the frame in the robot
base frame (mm, quaternion as above), ``oframe`` = identity. ABB expresses ``uframe`` in the
world frame: this equals jcalib's ``base`` when the robot's base frame coincides with world
(the default, no track or positioner).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.atomic import write_text_atomic
from jcalib.io.export._common import (
    check_identifier,
    checked_export,
    comment_text,
    fixed,
    frame_selection,
    provenance_lines,
    tool_pose,
)
from jcalib.io.result import ResultFile, TransformResult, load_result

__all__ = [
    "DEFAULT_TOOL_LOAD",
    "MM_DECIMALS",
    "QUAT_DECIMALS",
    "ToolLoad",
    "abb_pose_literal",
    "abb_rapid_module",
    "abb_tooldata",
    "abb_wobjdata",
    "write_abb_rapid",
]

#: Decimals of positions (mm): 0.001 mm.
MM_DECIMALS = 3
#: Decimals of quaternion components: 1e-6 (about 2e-6 rad).
QUAT_DECIMALS = 6
#: Decimals of the load mass (kg) and inertia (kg m²).
LOAD_DECIMALS = 3
#: RAPID identifiers: a letter, then letters, digits, ``_``; at most 32 characters.
RAPID_NAME_MAX = 32


@dataclass(frozen=True)
class ToolLoad:
    """Load data (``loaddata``) of a tool.

    Attributes:
        mass_kg: mass, kg, > 0 (RAPID rejects a tool with mass 0).
        cog_mm: centre of gravity in the flange (``tool0``) frame, mm; None = at the TCP.
        inertia_kgm2: moments of inertia ``(ix, iy, iz)`` about the centre of gravity, kg m²,
            with the axes of moment ``[1, 0, 0, 0]`` (aligned with the flange frame).
    """

    mass_kg: float = 1.0
    cog_mm: tuple[float, float, float] | None = None
    inertia_kgm2: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not np.isfinite(self.mass_kg) or self.mass_kg <= 0.0:
            raise BadInputError(
                f"mass_kg: expected a positive mass in kg (RAPID rejects 0), got {self.mass_kg!r}"
            )
        if self.cog_mm is not None:
            cog = np.asarray(self.cog_mm, dtype=np.float64)
            if cog.shape != (3,) or not np.all(np.isfinite(cog)):
                raise BadInputError(
                    f"cog_mm: expected 3 finite numbers (mm, flange frame), got {self.cog_mm!r}"
                )
        inertia = np.asarray(self.inertia_kgm2, dtype=np.float64)
        if inertia.shape != (3,) or not np.all(np.isfinite(inertia)) or np.any(inertia < 0):
            raise BadInputError(
                f"inertia_kgm2: expected 3 non-negative numbers (kg m²), got {self.inertia_kgm2!r}"
            )


#: The load written when none is given: 1 kg at the TCP, zero inertia.
DEFAULT_TOOL_LOAD = ToolLoad()


def _vec(values, decimals: int) -> str:
    return "[" + ", ".join(fixed(v, decimals) for v in values) + "]"


def abb_pose_literal(matrix) -> str:
    """The RAPID ``pose`` literal ``[[x, y, z], [q1, q2, q3, q4]]`` (mm, wxyz with q1 >= 0) of a
    4x4 transform in metres."""
    from jcalib.geometry.conversions import matrix_to_abb

    trans_mm, quat = matrix_to_abb(np.asarray(matrix, dtype=np.float64))
    return f"[{_vec(trans_mm, MM_DECIMALS)}, {_vec(quat, QUAT_DECIMALS)}]"


def abb_tooldata(result: ResultFile, tool: str, load: ToolLoad | None = None,
                 orientations: Mapping[str, np.ndarray] | None = None) -> str:
    """The ``tooldata`` literal of ``T_flange_<tool>``: ``[TRUE, [[x, y, z], [q1..q4]], [mass, ...]]``.

    Args:
        result: the calibration result.
        tool: the tool name (the result must hold ``T_flange_<tool>``).
        load: the tool's load; None = :data:`DEFAULT_TOOL_LOAD` (1 kg at the TCP).
        orientations: tool -> ``(3, 3)`` orientation supplied for a tool whose orientation the
            calibration did not determine (refused without it, see :func:`tool_pose`).
    """
    frame_selection(result, "flange", tool, "tool")
    T, _ = tool_pose(result, tool, orientations)
    load = DEFAULT_TOOL_LOAD if load is None else load
    cog = T[:3, 3] * 1e3 if load.cog_mm is None else np.asarray(load.cog_mm, dtype=np.float64)
    inertia = ", ".join(fixed(v, LOAD_DECIMALS) for v in load.inertia_kgm2)
    tload = (
        f"[{fixed(load.mass_kg, LOAD_DECIMALS)}, {_vec(cog, MM_DECIMALS)}, [1, 0, 0, 0], {inertia}]"
    )
    return f"[TRUE, {abb_pose_literal(T)}, {tload}]"


def abb_wobjdata(result: ResultFile, wobj: str) -> str:
    """The ``wobjdata`` literal of ``T_base_<wobj>``:
    ``[FALSE, TRUE, "", [[x, y, z], [q1..q4]], [[0, 0, 0], [1, 0, 0, 0]]]``."""
    frame_selection(result, "base", wobj, "wobj")
    T = result.transforms[f"T_base_{wobj}"].matrix
    return f'[FALSE, TRUE, "", {abb_pose_literal(T)}, [[0, 0, 0], [1, 0, 0, 0]]]'


def _position_std_mm(entry: TransformResult) -> str | None:
    """1-sigma position std of ``T_a_b``'s origin in frame *a* (mm), from the tangent covariance."""
    if entry.covariance is None:
        return None
    R = entry.matrix[:3, :3]
    cov_a = R @ entry.covariance[3:, 3:] @ R.T  # right perturbation: t' = t + R v to first order
    return "/".join(f"{v:.3f}" for v in np.sqrt(np.maximum(np.diag(cov_a), 0.0)) * 1e3)


def _names(chosen: dict[str, str | None], prefix: str, what: str) -> dict[str, str]:
    out = {}
    for frame, name in chosen.items():
        out[frame] = check_identifier(
            f"{prefix}{frame}" if name is None else name,
            f"{what} name for {frame!r}",
            RAPID_NAME_MAX,
        )
    seen: dict[str, str] = {}
    for frame, name in out.items():
        if name.lower() in seen:  # RAPID names are case-insensitive
            raise BadInputError(
                f"{what}: {frame!r} and {seen[name.lower()]!r} would both be called {name!r}"
            )
        seen[name.lower()] = frame
    return out


def abb_rapid_module(
    result: ResultFile,
    tools: Mapping[str, str] | Sequence[str] | str | None = None,
    wobjs: Mapping[str, str] | Sequence[str] | str | None = None,
    module: str = "jcalib_cal",
    loads: Mapping[str, ToolLoad] | None = None,
    orientations: Mapping[str, np.ndarray] | None = None,
) -> str:
    """A RAPID module declaring one ``PERS tooldata`` per tool and one ``PERS wobjdata`` per work
    object.

    Args:
        result: the calibration result.
        tools: tools to export (frames with ``T_flange_<tool>``): None = all of them (eye-in-hand
            cameras included), a name, a list, or a mapping tool -> RAPID name (default
            ``tool_<tool>``). Pass ``[]`` for none.
        wobjs: work objects (frames with ``T_base_<wobj>``, e.g. a fixed target): None = all of
            them, a name, a list, or a mapping -> RAPID name (default ``wobj_<wobj>``).
        module: the module name.
        loads: tool -> :class:`ToolLoad`; tools not listed get :data:`DEFAULT_TOOL_LOAD`.
        orientations: tool -> ``(3, 3)`` orientation for tools whose orientation was not calibrated.

    Raises:
        BadInputError: unknown tool/work object, an invalid or duplicate RAPID name, nothing to
            export, a tool whose orientation was not calibrated and is not supplied.
    """
    module = check_identifier(module, "module", RAPID_NAME_MAX)
    tool_names = _names(frame_selection(result, "flange", tools, "tools"), "tool_", "tool")
    wobj_names = _names(frame_selection(result, "base", wobjs, "wobjs"), "wobj_", "wobj")
    clash = {n.lower() for n in tool_names.values()} & {n.lower() for n in wobj_names.values()}
    if clash:
        raise BadInputError(f"tools/wobjs: the RAPID names {sorted(clash)} are used twice")
    if not tool_names and not wobj_names:
        raise BadInputError(
            "tools/wobjs: nothing to export: the result has no T_flange_<tool> or T_base_<wobj> "
            f"transforms (it has: {', '.join(result.transforms) or 'none'})"
        )
    loads = dict(loads or {})
    for tool in loads:
        if tool not in tool_names:
            raise BadInputError(
                f"loads: {tool!r} is not an exported tool ({', '.join(tool_names) or 'none'})"
            )
    lines = [f"MODULE {module}", "    ! Written by jcalib from a calibration result."]
    lines += [f"    ! {line}" for line in provenance_lines(result, ascii_only=True)]
    lines.append(
        "    ! Positions in mm, orientations as quaternions [q1, q2, q3, q4] = [w, x, y, z]."
    )
    for tool, name in tool_names.items():
        load = loads.get(tool)
        lines.append("")
        lines.append(f"    ! {name}: T_flange_{comment_text(tool, True)}, the TCP in the tool0 (flange) frame.")
        lines.append(f"    ! {comment_text(tool_pose(result, tool, orientations)[1], True)}.")
        std = _position_std_mm(result.transforms[f"T_flange_{tool}"])
        if std is not None:
            lines.append(f"    ! 1-sigma TCP position std x/y/z (tool0 frame): {std} mm.")
        if load is None:
            lines.append(
                "    ! Load: default 1 kg at the TCP (not calibrated); identify the real load before use."
            )
        lines.append(f"    PERS tooldata {name} := {abb_tooldata(result, tool, load, orientations)};")
    for wobj, name in wobj_names.items():
        lines.append("")
        lines.append(
            f"    ! {name}: T_base_{comment_text(wobj, True)}, the user frame in the robot base (= world) frame."
        )
        std = _position_std_mm(result.transforms[f"T_base_{wobj}"])
        if std is not None:
            lines.append(f"    ! 1-sigma origin position std x/y/z (base frame): {std} mm.")
        lines.append(f"    PERS wobjdata {name} := {abb_wobjdata(result, wobj)};")
    lines.append("ENDMODULE")
    return checked_export("\n".join(lines) + "\n", "rapid", ascii_only=True)


def write_abb_rapid(
    result: ResultFile | str | os.PathLike,
    path: str | os.PathLike,
    tools: Mapping[str, str] | Sequence[str] | str | None = None,
    wobjs: Mapping[str, str] | Sequence[str] | str | None = None,
    module: str = "jcalib_cal",
    loads: Mapping[str, ToolLoad] | None = None,
) -> Path:
    """Write :func:`abb_rapid_module` of ``result`` (a :class:`ResultFile` or a path) atomically
    (a ``.mod`` file)."""
    return write_text_atomic(
        path, abb_rapid_module(load_result(result), tools, wobjs, module, loads)
    )
