"""The fuzz suite's helpers: every file kind written fresh per test, the CLI run in-process, a
watchdog that turns a hang into a failure."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

import fuzz_files  # noqa: E402

#: No single fuzz test may take longer (s): a hang is a failure, not a stuck CI job.
WATCHDOG_S = 120


@pytest.fixture(autouse=True)
def watchdog():
    def fire(signum, frame):
        raise TimeoutError(f"fuzz test ran longer than {WATCHDOG_S} s (a hang)")

    old = signal.signal(signal.SIGALRM, fire)
    signal.alarm(WATCHDOG_S)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


@pytest.fixture
def inputs(tmp_path) -> dict[str, Path]:
    """One valid file of every kind (cell, observations, result, plan, pixels, points, scenario, session)."""
    return fuzz_files.write_all(tmp_path / "in")
