"""One capture per robot: an advisory lock named after the robot's address, held while a capture runs.

Two captures driving one robot into two sessions would each record poses the other commanded. The
lock is a ``flock`` on a file in the temporary directory named after the robot's address (and the
network namespace, where 127.0.0.1 of one namespace is not that of another): the kernel releases it
when its process ends, even by ``kill -9``, so a resumed capture gets it at once. It covers captures
started on this machine; a capture on another machine is caught by the check of measured against
commanded poses at every station (:func:`jcalib.acquisition.capture`), and an ABB controller's
socket server serves one client at a time anyway.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import tempfile
from pathlib import Path

from jcalib.errors import DeviceError


def _netns() -> int:
    try:
        return os.stat("/proc/self/ns/net").st_ino
    except OSError:
        return 0


def lock_path(address: str) -> Path:
    """The lock file of the robot at ``address`` (e.g. ``kuka://10.0.0.5:7000``)."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", address)[:200]
    return Path(tempfile.gettempdir()) / f"jcalib-robot-{_netns()}-{safe}.lock"


class RobotLock:
    """Hold the capture lock of one robot (context manager).

    Args:
        address: the robot's address as its driver reports it.
        owner: what to tell a second capture about this one (e.g. the session folder).

    Raises:
        DeviceError: another capture on this machine holds the robot (the message names its process
            and session).
    """

    def __init__(self, address: str, owner: str = "") -> None:
        self.address, self.path = address, lock_path(address)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                other = json.loads(os.pread(fd, 4096, 0).decode("utf-8", "replace") or "{}")
            except (OSError, ValueError):
                other = {}
            os.close(fd)
            raise DeviceError(
                f"robot {address} is being driven by another capture (process {other.get('pid', '?')}, "
                f"session {other.get('owner', '?')}); wait for it to finish or stop it, then retry"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps({"pid": os.getpid(), "owner": owner}).encode(), 0)
        self._fd = fd

    def release(self) -> None:
        """Give the robot free (idempotent)."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> "RobotLock":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def needs_lock(address: str) -> bool:
    """Network robots are locked; an in-process simulated robot (``sim://``) belongs to its process."""
    return address.split("://", 1)[0] in ("kuka", "abb", "ur")
