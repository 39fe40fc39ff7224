"""Goal-driven station planning and adaptive capture: which stations make what the user needs accurate.

Layer: above acquisition (candidate stations), problems and solve (the builder's predicted information)
and report (task-space quantities); below app. See :mod:`jcalib.planning.optimal`.
"""
