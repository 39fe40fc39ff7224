"""Make the sim tests' helper module (``sim_standins``) importable under ``--import-mode=importlib``."""

import os
import sys

sys.path.insert(0, os.path.dirname(__file__))
