"""The operator's web app (``jcalib ui``): live view, guided capture toward goals, inspect and fix, export.

A front end over the same functions as the command line (:mod:`jcalib.workflow`, :mod:`jcalib.pipeline`,
:func:`jcalib.calibrate`, :mod:`jcalib.io.export`): nothing is computed only here. See
:mod:`jcalib.ui.launch` (the command), :mod:`jcalib.ui.server` (pages, API, websockets),
:mod:`jcalib.ui.security` (token, hosts, the one controller) and :mod:`jcalib.ui.state`.

On the app layer: nothing below app imports it (the import-linter contracts in ``pyproject.toml``).
"""
