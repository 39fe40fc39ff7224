"""The operator's web app (``jcalib ui``, issue 30): a front end over the same functions as the CLI.

On the app layer: nothing below app imports it (the import-linter contracts in ``pyproject.toml``).
"""
