"""Who may talk to the operator app: the access token, the allowed hosts, and the robot's one controller.

Rules (checked by :class:`Guard`, an ASGI middleware in front of every route, static files and websockets
included):

- **Token.** A random token (printed in the URL the command shows, as Jupyter does) is required on every
  request: as ``?token=...`` (a page opened from that URL; the app then sets an HttpOnly, SameSite=Strict
  cookie and redirects to the URL without it), the cookie, or the ``X-Jcalib-Token`` header. No token:
  401; a wrong one: 403.
- **State changes** (any method but GET / HEAD) need the token in the ``X-Jcalib-Token`` header: a cookie
  alone is refused (403), so another web site cannot make the browser act (no cross-site requests).
- **Websockets** need the token in their query string and, when the browser sends one, an ``Origin`` of
  the app's own address.
- **Host header.** Only the address the app listens on (and ``localhost`` / ``127.0.0.1`` / ``[::1]`` with
  its port): a page on another name cannot reach it by DNS rebinding (403).

Files are reached only through ids (station, camera, export format), never through a path from the
request; :func:`inside` is the last check before a file is opened.

**One controller.** Of the browsers connected, one controls the cell (:class:`ControlLease`): it may
plan, capture, move, change settings, edit the cell and exclusions, calibrate. The others see the same
pages read-only until the controller leaves (its live connections closed for :data:`LEASE_TIMEOUT_S`) or
releases control. The STOP button works for everyone.
"""

from __future__ import annotations

import hmac
import secrets
import threading
import time
from pathlib import Path
from urllib.parse import parse_qs, urlencode

__all__ = ["Guard", "ControlLease", "new_token", "inside", "TOKEN_HEADER", "TOKEN_COOKIE", "LEASE_TIMEOUT_S"]

TOKEN_HEADER = "x-jcalib-token"
TOKEN_COOKIE = "jcalib_token"
CLIENT_HEADER = "x-jcalib-client"
#: A controller whose live connections have all been closed this long loses the lease, s.
LEASE_TIMEOUT_S = 10.0


def new_token() -> str:
    """A random access token (192 bits, URL-safe)."""
    return secrets.token_urlsafe(24)


def inside(path: Path, root: Path) -> bool:
    """Whether ``path`` (symlinks resolved) lies inside ``root`` (resolved)."""
    try:
        path.resolve(strict=False).relative_to(root.resolve(strict=False))
        return True
    except ValueError:
        return False


def _cookie(headers: list[tuple[bytes, bytes]]) -> str | None:
    for name, value in headers:
        if name == b"cookie":
            for part in value.decode("latin-1").split(";"):
                key, _, val = part.strip().partition("=")
                if key == TOKEN_COOKIE:
                    return val
    return None


def _header(headers: list[tuple[bytes, bytes]], key: bytes) -> str | None:
    for name, value in headers:
        if name == key:
            return value.decode("latin-1")
    return None


class Guard:
    """ASGI middleware enforcing the rules of the module docstring.

    Args:
        app: the wrapped ASGI application.
        token: the access token.
        hosts: ``host:port`` values accepted in the ``Host`` header (and as ``http://host:port`` origins).
    """

    def __init__(self, app, token: str, hosts: set[str]) -> None:
        self.app = app
        self.token = token
        self.hosts = {h.lower() for h in hosts}

    def _valid(self, candidate: str | None) -> bool:
        return candidate is not None and hmac.compare_digest(candidate.encode(), self.token.encode())

    async def __call__(self, scope, receive, send):
        kind = scope["type"]
        if kind not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        headers = scope.get("headers") or []
        host = (_header(headers, b"host") or "").lower()
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        q_token = (query.get("token") or [None])[0]
        if host not in self.hosts:
            return await self._refuse(kind, send, 403, f"host {host!r} is not this app's address")
        if kind == "websocket":
            origin = _header(headers, b"origin")
            if origin is not None and origin.lower().removeprefix("http://") not in self.hosts:
                return await self._refuse(kind, send, 403, "cross-origin websocket")
            if q_token is None:
                return await self._refuse(kind, send, 401, "token required")
            if not self._valid(q_token):
                return await self._refuse(kind, send, 403, "wrong token")
            return await self.app(scope, receive, send)
        method = scope.get("method", "GET")
        h_token = _header(headers, TOKEN_HEADER.encode())
        if method not in ("GET", "HEAD"):
            if h_token is None:
                why = "state-changing requests need the token in the X-Jcalib-Token header"
                return await self._refuse(kind, send, 401 if _cookie(headers) is None else 403, why)
            if not self._valid(h_token):
                return await self._refuse(kind, send, 403, "wrong token")
            return await self.app(scope, receive, send)
        given = h_token or q_token or _cookie(headers)
        if given is None:
            return await self._refuse(kind, send, 401, "token required: open the URL the jcalib ui command printed")
        if not self._valid(given):
            return await self._refuse(kind, send, 403, "wrong token")
        if q_token is not None and h_token is None:  # set the cookie, drop the token from the address bar
            rest = {k: v for k, v in query.items() if k != "token"}
            location = scope.get("path", "/") + (("?" + urlencode(rest, doseq=True)) if rest else "")
            cookie = f"{TOKEN_COOKIE}={self.token}; HttpOnly; SameSite=Strict; Path=/"
            await send({"type": "http.response.start", "status": 303,
                        "headers": [(b"location", location.encode()), (b"set-cookie", cookie.encode()),
                                    (b"cache-control", b"no-store"), (b"content-length", b"0")]})  # fmt: skip
            await send({"type": "http.response.body", "body": b""})
            return
        return await self.app(scope, receive, send)

    @staticmethod
    async def _refuse(kind: str, send, status: int, why: str) -> None:
        if kind == "websocket":
            # closing before accepting makes the server answer the handshake with HTTP 403
            await send({"type": "websocket.close", "code": 1008, "reason": why[:120]})
            return
        body = f"jcalib ui: {status} {why}\n".encode()
        await send({"type": "http.response.start", "status": status,
                    "headers": [(b"content-type", b"text/plain; charset=utf-8"),
                                (b"content-length", str(len(body)).encode())]})  # fmt: skip
        await send({"type": "http.response.body", "body": body})


class ControlLease:
    """Which browser controls the cell (module docstring). Clients are random ids made by each page."""

    def __init__(self, timeout_s: float = LEASE_TIMEOUT_S) -> None:
        self.timeout_s = float(timeout_s)
        self._lock = threading.Lock()
        self.holder: str | None = None
        self._connections: dict[str, int] = {}
        self._last_seen: dict[str, float] = {}

    def connected(self, client: str) -> None:
        """A live connection of ``client`` opened."""
        with self._lock:
            self._connections[client] = self._connections.get(client, 0) + 1
            self._last_seen[client] = time.monotonic()

    def disconnected(self, client: str) -> None:
        """A live connection of ``client`` closed."""
        with self._lock:
            n = self._connections.get(client, 0) - 1
            if n <= 0:
                self._connections.pop(client, None)
            else:
                self._connections[client] = n
            self._last_seen[client] = time.monotonic()

    def _holder_gone(self) -> bool:
        h = self.holder
        if h is None:
            return True
        if self._connections.get(h, 0) > 0:
            return False
        return time.monotonic() - self._last_seen.get(h, 0.0) > self.timeout_s

    def acquire(self, client: str) -> bool:
        """Make ``client`` the controller when nobody holds the lease or its holder has left (no live
        connection for :attr:`timeout_s`). Returns whether ``client`` holds it now."""
        with self._lock:
            if self.holder == client or self._holder_gone():
                self.holder = client
                self._last_seen[client] = time.monotonic()  # a request counts as being there
                return True
            return False

    def holds(self, client: str | None) -> bool:
        """Whether ``client`` controls the cell; a client asking while nobody does gets the lease."""
        if not client:
            return False
        return self.acquire(client)

    def release(self, client: str) -> None:
        with self._lock:
            if self.holder == client:
                self.holder = None

    def status(self, client: str | None) -> dict:
        with self._lock:
            gone = self._holder_gone()
            return {"holder": None if gone else self.holder, "you": bool(client) and self.holder == client and not gone,
                    "clients": len(self._connections)}
