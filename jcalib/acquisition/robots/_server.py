"""A small threaded TCP server base for the simulated controllers (loopback by default)."""

from __future__ import annotations

import ipaddress
import socket
import threading

from jcalib.errors import BadInputError


def check_loopback(host: str, allow_non_loopback: bool) -> None:
    """Refuse to listen on a non-loopback address unless explicitly allowed."""
    try:
        loop = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loop = host == "localhost"
    if not loop and not allow_non_loopback:
        raise BadInputError(
            f"host: simulators listen on loopback (127.0.0.0/8) unless told otherwise, got {host!r}; "
            "pass allow_non_loopback=True to expose one on a network"
        )


class ThreadedTcpServer:
    """Accepts connections on ``(host, port)`` and serves each in its own daemon thread.

    Subclasses implement :meth:`serve_connection`. ``port=0`` picks a free port (see :attr:`port`).
    Use :meth:`start` / :meth:`stop` (or ``with``) to run it in a background thread of this process.

    A client that sends nothing for ``idle_timeout_s`` is disconnected (a real controller's socket
    task times out the same way), and a client whose bytes make no sense is disconnected: neither can
    hold the server. :attr:`num_dropped` counts such disconnections.
    """

    name = "server"

    def __init__(
        self, host: str = "127.0.0.1", port: int = 0, *, allow_non_loopback: bool = False, idle_timeout_s: float = 30.0
    ):
        check_loopback(host, allow_non_loopback)
        if not idle_timeout_s > 0:
            raise BadInputError(f"idle_timeout_s: expected a positive number of seconds, got {idle_timeout_s!r}")
        self.idle_timeout_s = float(idle_timeout_s)
        self.num_dropped = 0
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.bind((host, port))
        self._sock.listen(8)
        self.host, self.port = self._sock.getsockname()[:2]
        self._stop = threading.Event()
        self._clients: set[socket.socket] = set()
        self._clients_lock = threading.Lock()
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    def serve_connection(self, conn: socket.socket) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _run_client(self, conn: socket.socket) -> None:
        try:
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.serve_connection(conn)
        except OSError:
            pass  # client went away, timed out while idle, or the server is stopping
        except Exception:  # noqa: BLE001 - a malformed request ends that client's connection, never the server
            self.num_dropped += 1
        finally:
            with self._clients_lock:
                self._clients.discard(conn)
            try:
                conn.close()
            except OSError:
                pass

    def serve_forever(self) -> None:
        """Accept clients until :meth:`stop`."""
        self._sock.settimeout(0.1)
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except socket.timeout:
                continue
            except OSError:
                break
            conn.settimeout(self.idle_timeout_s)
            with self._clients_lock:
                self._clients.add(conn)
            threading.Thread(target=self._run_client, args=(conn,), daemon=True).start()

    def start(self) -> "ThreadedTcpServer":
        """Serve in a daemon thread of this process; returns self."""
        self._thread = threading.Thread(target=self.serve_forever, name=self.name, daemon=True)
        self._thread.start()
        return self

    def drop_clients(self) -> None:
        """Close every client connection (simulates a lost network link; the server keeps listening)."""
        with self._clients_lock:
            clients = list(self._clients)
        for c in clients:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()

    def stop(self) -> None:
        """Stop accepting, drop the clients, release the port."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.drop_clients()
        self._sock.close()

    def __enter__(self):
        return self.start() if self._thread is None else self

    def __exit__(self, *exc) -> None:
        self.stop()
