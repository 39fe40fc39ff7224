"""Make the shared synthetic problems of tests/solve importable as ``solve_problems``."""

import os
import sys

sys.path.insert(0, os.path.dirname(__file__))
