"""The steps a cell's operator runs with devices and sessions, shared by the command line and the app.

- :mod:`jcalib.workflow.devices`: robots and cameras from URLs, capture settings;
- :mod:`jcalib.workflow.plan`: ``jcalib plan`` (every planner kind, its options and what it prints);
- :mod:`jcalib.workflow.capture`: a station plan captured with open devices (``jcalib capture --plan``);
- :mod:`jcalib.workflow.adaptive`: adaptive capture toward goals (``jcalib capture --goal``);
- :mod:`jcalib.workflow.simulate`: the demo's simulated cell and its simulator process.

Layer: above acquisition, planning, pipeline and problems; below app (the ``jcalib`` command) and ui (the
operator app), which both call these and compute nothing of their own.
"""
