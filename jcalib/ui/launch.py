"""``jcalib ui``: start the operator app (and, with ``--simulate``, the simulated cell it drives).

The server listens on 127.0.0.1 unless ``--host`` says otherwise, and prints its URL with the access token
(``http://127.0.0.1:PORT/?token=...``). With ``--simulate`` the simulated cell of ``jcalib demo`` (a
KUKA-protocol robot and two fake GigE cameras, :mod:`jcalib.workflow.simulate`) runs in a private network
namespace (:mod:`jcalib.acquisition.netns`) together with the app, whose listening socket is opened in the
host's namespace *before* entering it: the host's browser reaches the app, nothing reaches the devices.
"""

from __future__ import annotations

import argparse
import errno
import ipaddress
import os
import socket
import sys
from pathlib import Path

from jcalib.errors import BadInputError

__all__ = ["run_ui", "DEFAULT_PORT"]

DEFAULT_PORT = 8765
# How long a stopping app waits for a running calibration or report to finish (a capture is stopped at once).
SHUTDOWN_WAIT_S = 60.0
#: Ports tried after the default one when it is taken (not with an explicit --port).
PORT_TRIES = 20
TOKEN_ENV = "JCALIB_UI_TOKEN"


def _bind(host: str, port: int | None) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    tries = [port] if port is not None else [DEFAULT_PORT + k for k in range(PORT_TRIES)]
    last = None
    for p in tries:
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, p))
        except OSError as e:
            sock.close()
            last = e
            if e.errno in (errno.EADDRINUSE, errno.EACCES) and port is None:
                continue
            break
        sock.listen(128)
        sock.set_inheritable(True)
        return sock
    where = f"{host}:{port}" if port is not None else f"{host}:{tries[0]}..{tries[-1]}"
    raise BadInputError(f"--port: cannot listen on {where}: {last}; choose another --port (0: any free port)")


def _check_host(host: str) -> None:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        if host != "localhost":
            raise BadInputError(f"--host: expected an IP address of this machine (e.g. 127.0.0.1), got {host!r}") from None


def run_ui(*, cell: Path | None, session: Path, robot: str | None, cameras: dict[str, str], simulate: bool,
           port: int | None, host: str, image_size: str = "640x480", seed: int = 0,
           print_url=print) -> int:  # fmt: skip
    """Start the app (see the module docstring); returns the exit status when the server stops.

    Args:
        cell: the cell spec file (None: the session's, or with ``simulate`` the demo cell written into the
            session folder).
        session: the capture session folder (created by the first capture; an existing one is continued).
        robot, cameras: device URLs (``kuka://...``, ``abb://...``; camera id -> ``gige://...`` / ``replay://...``).
        simulate: start the simulated cell instead (no ``robot`` / ``cameras`` then).
        port: TCP port (None: 8765 or the next free one; 0: any free port).  host: address to listen on.
        image_size: ``--simulate``: image size of the simulated cameras without intrinsics.
        seed: ``--simulate``: noise seed of the simulated cell.

    Raises:
        BadInputError: contradicting options, a missing or invalid cell, a port that cannot be used.
    """
    _check_host(host)
    if simulate and (robot or cameras):
        raise BadInputError("--simulate starts its own robot and cameras; leave out --robot and --camera")
    if session.exists() and not session.is_dir():
        raise BadInputError(f"--session {session}: exists and is not a folder")
    if cell is not None and not cell.is_file():
        raise BadInputError(f"--cell {cell}: no such file")
    if cell is None and not simulate and not (session / "session.json").is_file():
        raise BadInputError("jcalib ui: give the cell spec (--cell CELL), a session to continue (--session DIR), "
                            "or --simulate for the simulated cell")
    from jcalib.acquisition.netns import in_private_namespace, run_in_private_namespace
    from jcalib.ui.security import new_token

    inherited = os.environ.get("JCALIB_UI_FD")
    sock = socket.socket(fileno=int(inherited)) if inherited else _bind(host, port)
    token = os.environ.get(TOKEN_ENV) or new_token()
    if simulate and not in_private_namespace():
        from jcalib.workflow.simulate import DEMO_ADDRESSES

        env = {**os.environ, TOKEN_ENV: token, "JCALIB_UI_FD": str(sock.fileno())}
        argv = [sys.executable, "-m", "jcalib.ui.launch", "--session", str(session), "--simulate", "--host", host,
                "--port", str(sock.getsockname()[1]), "--image-size", image_size, "--seed", str(int(seed))]
        if cell is not None:
            argv += ["--cell", str(cell)]
        return run_in_private_namespace(argv, addresses=[a for a in DEMO_ADDRESSES.values() if a != "127.0.0.1"],
                                        pass_fds=[sock.fileno()], env=env, what="jcalib ui --simulate")
    return _serve(sock, token, cell=cell, session=session, robot=robot, cameras=cameras, simulate=simulate,
                  host=host, image_size=image_size, seed=seed, print_url=print_url)


def _server_class():
    import uvicorn

    class Server(uvicorn.Server):
        """uvicorn's server, except that Ctrl-C or a terminate ends the app with exit status 0 after its clean
        shutdown (uvicorn re-raises the signal after shutting down, which would end the process by it)."""

        def handle_exit(self, sig, frame) -> None:
            super().handle_exit(sig, frame)
            captured = getattr(self, "_captured_signals", None)
            if isinstance(captured, list):
                captured.clear()

    return Server


def _serve(sock: socket.socket, token: str, *, cell, session: Path, robot, cameras, simulate: bool, host: str,
           image_size: str, seed: int, print_url) -> int:  # fmt: skip
    import uvicorn

    from jcalib.io.atomic import write_text_atomic
    from jcalib.solve import reuse_compiled_shapes

    _Server = _server_class()
    from jcalib.ui.server import make_app
    from jcalib.ui.state import AppState, UIConfig

    session = session.resolve()
    simulator = None
    reuse_compiled_shapes(True)  # a re-solve after an exclusion runs at the compiled shape (warm)
    if cell is None:
        cell = session / "cell.yaml"
        if not cell.is_file():
            session.mkdir(parents=True, exist_ok=True)
            if simulate:
                from jcalib.workflow.simulate import DEMO_CELL

                write_text_atomic(cell, DEMO_CELL)
            else:
                import yaml

                from jcalib.io.session import read_session

                meta, _ = read_session(session)
                if not meta.get("cell"):
                    raise BadInputError(f"--session {session}: the session holds no cell spec; give --cell CELL")
                write_text_atomic(cell, yaml.safe_dump(meta["cell"], sort_keys=False))
    cell = Path(cell).resolve()
    try:
        if simulate:
            from jcalib.workflow.simulate import DEMO_ADDRESSES, start_simulator

            session.mkdir(parents=True, exist_ok=True)
            simulator = start_simulator(cell, addresses=DEMO_ADDRESSES, log_path=session / "simulate.log",
                                        image_size=image_size, seed=seed, time_scale=1.0, fast_noise=True)
            robot, cameras = simulator.robot_url, simulator.camera_urls
        config = UIConfig(cell_path=cell, session_dir=session, robot_url=robot, camera_urls=dict(cameras),
                          simulated=simulate, title=("simulated cell" if simulate else cell.name))
        state = AppState(config)
        state.open_devices()
        port = sock.getsockname()[1]
        hosts = {f"127.0.0.1:{port}", f"localhost:{port}", f"[::1]:{port}", f"{host}:{port}"}
        app = make_app(state, token, hosts)
        shown = f"[{host}]" if ":" in host else host
        if host not in ("127.0.0.1", "::1", "localhost"):
            print_url(f"jcalib ui: listening on {host}, reachable from other machines; share the URL only with "
                      "who may control the cell")
        print_url(f"jcalib ui: http://{shown}:{port}/?token={token}")
        if state.device_error:
            print_url(f"jcalib ui: device problem: {state.device_error}")
        sys.stdout.flush()
        # No per-message deflate: the live frames are JPEG (deflate only spends the CPU that detection needs).
        server = _Server(uvicorn.Config(app, fd=sock.fileno(), log_level="warning", ws="websockets-sansio",
                                        ws_per_message_deflate=False, lifespan="on",
                                        timeout_graceful_shutdown=3))  # fmt: skip
        server.run()
        state.begin_close()
        left = state.join_background(timeout_s=SHUTDOWN_WAIT_S)
        if left:
            # The interpreter's exit would abort (a thread inside XLA or OpenCV): end without it, files are
            # written atomically, so nothing half-written stays behind.
            print_url(f"jcalib ui: stopped while {', '.join(left)} still ran; it was abandoned")
            sys.stdout.flush()
            sys.stderr.flush()
            if simulator is not None:
                simulator.stop()
            os._exit(0)
        return 0
    finally:
        if simulator is not None:
            simulator.stop()


def main(argv: list[str] | None = None) -> int:
    """Entry point inside the private namespace (``python -m jcalib.ui.launch``): the options of ``jcalib ui``."""
    p = argparse.ArgumentParser(prog="jcalib ui")
    p.add_argument("--cell", type=Path)
    p.add_argument("--session", type=Path, required=True)
    p.add_argument("--simulate", action="store_true")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int)
    p.add_argument("--image-size", default="640x480")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    return run_ui(cell=a.cell, session=a.session, robot=None, cameras={}, simulate=a.simulate, port=a.port,
                  host=a.host, image_size=a.image_size, seed=a.seed)


if __name__ == "__main__":
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    from jcalib.solve.cache import enable_compilation_cache

    enable_compilation_cache()
    try:
        sys.exit(main())
    except Exception as e:  # one paragraph, like the CLI
        from jcalib.errors import JcalibError

        if isinstance(e, JcalibError):
            print(f"jcalib error: {e}", file=sys.stderr)
            sys.exit(getattr(e, "exit_code", 1))
        raise
