"""A private network namespace for simulated devices: nothing they serve reaches a real interface.

GigE Vision's control port is fixed (UDP 3956), so two simulated cameras need two addresses; Aravis' fake
camera binds to the interface that owns its address. A simulated cell (``jcalib demo``,
``jcalib ui --simulate``) therefore runs in a new network namespace (``unshare -n``; ``unshare -rn``, a
user namespace, when not root) in which only ``lo`` is up, with 127.0.0.1 and the extra loopback
addresses its cameras use. Nothing is broadcast on real interfaces and no port of the host is taken.

A listening socket created *before* entering the namespace stays in the host's namespace: passed through
(``pass_fds``), it lets a server inside the namespace (the operator app) stay reachable from the host's
browser while its devices are not.
"""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import threading
from collections.abc import Mapping, Sequence

from jcalib.errors import DeviceError

#: Set (to "1") in the environment of a process started by :func:`run_in_private_namespace`.
NETNS_ENV = "JCALIB_IN_PRIVATE_NETNS"

__all__ = ["NETNS_ENV", "in_private_namespace", "run_in_private_namespace"]


def in_private_namespace() -> bool:
    """Whether this process was started by :func:`run_in_private_namespace`."""
    return os.environ.get(NETNS_ENV) == "1"


def run_in_private_namespace(
    argv: Sequence[str],
    *,
    addresses: Sequence[str] = ("127.0.0.2",),
    pass_fds: Sequence[int] = (),
    env: Mapping[str, str] | None = None,
    what: str = "the simulated cell",
) -> int:
    """Run the command ``argv`` in a new network namespace with ``lo`` up and ``addresses`` on it.

    Args:
        argv: the command (e.g. ``[sys.executable, "-m", "jcalib.app.demo_cell", ...]``).
        addresses: extra loopback addresses (127.x.y.z) to assign to ``lo``.
        pass_fds: file descriptors the command inherits (e.g. a listening socket of the host's namespace).
        env: the environment (default: this process's), with :data:`NETNS_ENV` set.
        what: named in the error when the namespace cannot be made.

    Returns:
        The command's exit status.

    Raises:
        DeviceError: ``unshare`` or ``ip`` is missing.
    """
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        raise DeviceError(
            f"{what} needs a private network namespace (util-linux `unshare` and iproute2 `ip`); install them "
            "(./scripts/setup does)"
        )
    flags = "-n" if os.geteuid() == 0 else "-rn"
    steps = ["ip link set lo up"] + [f"ip addr add {shlex.quote(a)}/8 dev lo" for a in addresses]
    inner = " && ".join(steps) + " && exec " + shlex.join(list(argv))
    full_env = {**(env if env is not None else os.environ), NETNS_ENV: "1"}
    # unshare and sh exec the command, so signals to the child's pid reach it. A terminate sent to this
    # process is forwarded (the command shuts down cleanly while this process waits for it); Ctrl-C reaches
    # the whole foreground process group, the command included, so here it is only ignored.
    proc = subprocess.Popen(["unshare", flags, "sh", "-c", inner], env=full_env, pass_fds=tuple(pass_fds))
    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, lambda signum, frame: proc.send_signal(signum))
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        return proc.wait()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
