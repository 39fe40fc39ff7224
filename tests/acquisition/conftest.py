"""Fixtures of the acquisition tests: Aravis must be there whenever the setup was able to install it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def aravis_should_be_installed() -> bool:
    """True when scripts/apt-packages.txt lists Aravis and this machine's setup installs Debian packages
    (CI, or running as root): then a missing Aravis is a setup failure, not a reason to skip."""
    try:
        listed = "gir1.2-aravis-0.8" in (ROOT / "scripts" / "apt-packages.txt").read_text()
    except OSError:
        listed = False
    return listed and (bool(os.environ.get("CI")) or os.geteuid() == 0)


@pytest.fixture(scope="session")
def aravis():
    """Skip (developer machine without root) or fail (CI / root) when Aravis 0.8 is unusable."""
    from jcalib.acquisition.cameras.aravis import INSTALL_HINT, aravis_available
    from jcalib.acquisition.cameras.fake_gige import load_libraries

    problem = None
    if not aravis_available():
        problem = "Aravis 0.8 is not importable through PyGObject"
    else:
        try:
            load_libraries()
        except Exception as e:  # DeviceError: libaravis-0.8.so.0 missing
            problem = str(e)
    if problem:
        msg = f"{problem}. {INSTALL_HINT}."
        if aravis_should_be_installed():
            pytest.fail(
                msg + " scripts/apt-packages.txt lists these packages, so ./scripts/setup should have "
                "installed them: the setup is broken, not the test.",
                pytrace=False,
            )
        pytest.skip(msg + " (no root and not CI: the setup could not install them)")
