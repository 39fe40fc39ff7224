"""Start of the cells whose tool tips a 3-D point sensor measures (a laser tracker and its reflector).

For each (point sensor, tool) group whose sensor is fixed in the cell and whose tool rides on a flange:
the sensor's pose ``T_<frame>_<sensor>`` and the tip ``T_flange_<tool>`` (translation; the rotation is the
tool's stated orientation, else identity and held) come from the closed form of
:func:`jcalib.init.point_sensor.point_sensor_start`, or the tip alone from a sensor pose already known.
"""

from __future__ import annotations

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import make_pose
from jcalib.init.point_sensor import point_sensor_start
from jcalib.problems.graph import Graph
from jcalib.problems.tools import given_orientation

__all__ = ["start_point_sensors"]


def start_point_sensors(g: Graph, start) -> None:
    """Fill ``start.known`` with every point sensor's mount pose and the tips it measures (m).

    Raises:
        BadInputError: a point sensor on a flange, or a measured tool not on a robot (not supported).
        NotObservableError: too few stations or too little rotation to start them.
    """
    cell = g.cell
    for (sensor, tool), ps in g.positions.items():
        S, T = g.mount_name(cell.cameras[sensor]), f"T_flange_{tool}"
        h_tool = g.holder(cell.tools[tool])
        if g.holder(cell.cameras[sensor]) is not None:
            raise BadInputError(f"{cell.source}: sensor '{sensor}' (kind point) is on a flange; a point sensor is "
                                "fixed in the cell (mount: base, or world with several robots)")
        ks = np.asarray(ps.stations)
        F = g.flange[h_tool][ks]
        base = g.base_name(h_tool)
        if base is not None:
            if base not in start.known:
                raise BadInputError(f"{cell.source}: tool '{tool}' measured by '{sensor}' rides on {g.label(h_tool)}, "
                                    f"whose base {base} is not determined by the rest of the cell")
            F = start.known[base] @ F
        P = np.stack(ps.p_sensor_tool)
        if S in start.known:
            p_cell = P @ start.known[S][:3, :3].T + start.known[S][:3, 3]
            tip = np.mean(np.einsum("nba,nb->na", F[:, :3, :3], p_cell - F[:, :3, 3]), axis=0)
            how = f"from:{S}+{sensor}/{tool}"
        else:
            start.known[S], tip = point_sensor_start(F, P, f"point sensor '{sensor}' and tool '{tool}'")
            start.how[S] = how = "point_sensor"
        if T not in start.known:
            R0 = given_orientation(cell.tools[tool])
            start.known[T] = make_pose(np.eye(3) if R0 is None else R0, tip)
            start.how[T] = how
