"""Station planning: which flange poses (stations) a capture visits, and which make what the user needs accurate.

- :mod:`jcalib.planning.layout`: the nominal cell (:func:`cell_layout`) every planner works on;
- :mod:`jcalib.planning.stations`: the planners of ``jcalib plan --kind viewsets|handeye|tcp|kinematics``
  (:func:`plan_cell`, :func:`plan_kinematics`);
- :mod:`jcalib.planning.kinematic_design`: the D-optimal design of kinematic calibration stations;
- :mod:`jcalib.planning.robocalib`: the RoboCalib thesis' hand-eye stations and camera view sets;
- :mod:`jcalib.planning.candidates`: candidate stations for goal-driven planning;
- :mod:`jcalib.planning.predict`, :mod:`jcalib.planning.optimal`: the predicted σ of a goal and the stations
  chosen for it (``jcalib plan --kind optimal``); :mod:`jcalib.planning.adaptive`: adaptive capture toward
  goals (``jcalib capture --goal``).

Layer: above problems and solve (the builder's predicted information, the task-space σ of
:mod:`jcalib.problems.taskspace` and :mod:`jcalib.problems.goals`), init, io and geometry; below app.
Acquisition never imports planning: a capture is handed its stations (a :class:`jcalib.io.plan.Plan`).
The re-exports below are the light modules (numpy and geometry); the goal-driven ones load the problem
builder and are imported from their modules.
"""

from jcalib.planning.layout import CellLayout, cell_layout
from jcalib.planning.robocalib import RoboCalibPlan, handeye_stations, viewset_stations
from jcalib.planning.stations import KINDS, PlannedStations, plan_cell, plan_kinematics

__all__ = [
    "KINDS",
    "CellLayout",
    "PlannedStations",
    "RoboCalibPlan",
    "cell_layout",
    "handeye_stations",
    "plan_cell",
    "plan_kinematics",
    "viewset_stations",
]
