"""Devices from URLs, for the command line and the app alike.

Robots: ``kuka://HOST[:PORT]`` (KUKAVARPROXY, 7000), ``abb://HOST[:PORT]`` (jcalib RAPID server, 5515) and
``ur://HOST`` (Universal Robots: RTDE 30004, URScript on the secondary interface 30002; ``ur://HOST:RTDE:SCRIPT``
names other ports, e.g. a simulator's free ones).
Cameras: ``gige://IPV4`` (opened by address, never by discovery) and ``replay://FOLDER``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from jcalib.acquisition.cameras.base import Camera
from jcalib.acquisition.robots.base import Robot
from jcalib.errors import BadInputError

__all__ = ["open_robot", "open_camera", "close_devices", "check_urls", "parse_named", "parse_image_size",
           "parse_settings", "capture_settings", "ROBOT_SCHEMES", "CAMERA_SCHEMES"]

ROBOT_SCHEMES = ("kuka", "abb", "ur")
CAMERA_SCHEMES = ("gige", "replay")


def _split(url: str, what: str, schemes: tuple[str, ...]) -> tuple[str, str]:
    scheme, sep, rest = url.partition("://") if isinstance(url, str) else ("", "", "")
    if not sep or scheme not in schemes or not rest:
        raise BadInputError(f"{what}: expected {' or '.join(s + '://...' for s in schemes)}, got {url!r}")
    return scheme, rest


def check_urls(robot_url: str | None, camera_urls: Mapping[str, str]) -> None:
    """Refuse malformed device URLs before anything is opened (naming the option)."""
    if robot_url is not None:
        scheme, rest = _split(robot_url, "--robot", ROBOT_SCHEMES)
        if scheme == "ur":
            _ur_ports(rest, robot_url)
    for name, url in camera_urls.items():
        _split(url, f"--camera {name}", CAMERA_SCHEMES)


def _ur_ports(rest: str, url: str) -> tuple[str, int, int]:
    from jcalib.acquisition.robots.rtde import RTDE_PORT, SCRIPT_PORT

    host, *ports = rest.split(":")
    if not host or len(ports) not in (0, 2):
        raise BadInputError(f"--robot: expected ur://HOST (or ur://HOST:RTDE_PORT:SCRIPT_PORT), got {url!r}")
    try:
        rtde_port, script_port = (int(p) for p in ports) if ports else (RTDE_PORT, SCRIPT_PORT)
    except ValueError:
        raise BadInputError(f"--robot: ports must be numbers, got {url!r}") from None
    if not (0 < rtde_port < 65536 and 0 < script_port < 65536):
        raise BadInputError(f"--robot: ports must be in 1..65535, got {url!r}")
    return host, rtde_port, script_port


def open_robot(url: str, **kw: Any) -> Robot:
    """Connect to the robot at ``kuka://HOST[:PORT]``, ``abb://HOST[:PORT]`` or ``ur://HOST[:RTDE:SCRIPT]``."""
    scheme, rest = _split(url, "--robot", ROBOT_SCHEMES)
    if scheme == "ur":
        from jcalib.acquisition.robots.ur import UrRobot

        host, rtde_port, script_port = _ur_ports(rest, url)
        return UrRobot(host, rtde_port=rtde_port, script_port=script_port, **kw)
    host, _, port = rest.partition(":")
    try:
        port_n = int(port) if port else (7000 if scheme == "kuka" else 5515)
    except ValueError:
        raise BadInputError(f"--robot: port must be a number, got {port!r} in {url!r}") from None
    if scheme == "kuka":
        from jcalib.acquisition.robots.kuka import KukaRobot

        return KukaRobot(host, port_n, **kw)
    from jcalib.acquisition.robots.abb import AbbRobot

    return AbbRobot(host, port_n, **kw)


def open_camera(name: str, url: str, **kw: Any) -> Camera:
    """Open camera ``name`` at ``gige://IPV4`` or ``replay://FOLDER``."""
    scheme, rest = _split(url, f"--camera {name}", CAMERA_SCHEMES)
    if scheme == "gige":
        from jcalib.acquisition.cameras.aravis import GigECamera

        return GigECamera(rest, name=name, **kw)
    from jcalib.acquisition.cameras.simulated import ReplayCamera

    return ReplayCamera(rest, name=name)


def close_devices(cameras: Mapping[str, Camera], robot: Robot | None) -> None:
    """Close a capture's cameras, then its robot (``None`` when it was never opened)."""
    for c in cameras.values():
        c.close()
    if robot is not None:
        robot.close()


def parse_named(values: Sequence[str], what: str = "--camera") -> dict[str, str]:
    """``["cam0=gige://10.0.0.5", ...]`` -> ``{"cam0": "gige://10.0.0.5", ...}`` (names unique)."""
    out: dict[str, str] = {}
    for v in values:
        name, sep, value = v.partition("=")
        name, value = name.strip(), value.strip()
        if not sep or not name or not value:
            raise BadInputError(f"{what}: expected NAME=VALUE such as cam0=gige://192.168.10.20, got {v!r}")
        if name in out:
            raise BadInputError(f"{what}: camera {name!r} is given twice")
        out[name] = value
    return out


def parse_image_size(text: str | None) -> tuple[int, int] | None:
    """``"640x480"`` -> ``(640, 480)``."""
    if text is None:
        return None
    w, sep, h = text.lower().partition("x")
    try:
        if not sep:
            raise ValueError
        size = int(w), int(h)
    except ValueError:
        raise BadInputError(f"--image-size: expected WIDTHxHEIGHT such as 640x480, got {text!r}") from None
    if not (8 <= size[0] <= 16384 and 8 <= size[1] <= 16384):
        raise BadInputError(f"--image-size: expected 8..16384 pixels per side, got {text!r}")
    return size


def parse_settings(values: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``["cam0.ExposureTime=5000", "cam0.PixelFormat=Mono8"]`` -> ``{"cam0": {"ExposureTime": 5000, ...}}``.

    Values that read as integers or finite decimals become numbers, the rest stay strings.
    """
    out: dict[str, dict[str, Any]] = {}
    for v in values:
        key, sep, text = v.partition("=")
        cam, dot, feature = key.strip().partition(".")
        text = text.strip()
        if not sep or not dot or not cam or not feature or not text:
            raise BadInputError(f"--setting: expected CAMERA.FEATURE=VALUE such as cam0.ExposureTime=5000, got {v!r}")
        value: Any = text
        for conv in (int, float):
            try:
                value = conv(text)
                break
            except ValueError:
                continue
        if isinstance(value, float) and not math.isfinite(value):
            raise BadInputError(f"--setting {key}: expected a finite number or a word, got {text!r}")
        out.setdefault(cam, {})[feature] = value
    return out


def capture_settings(cell: Any, cli: Mapping[str, Mapping[str, Any]] | None) -> dict[str, dict[str, Any]]:
    """Camera settings of a capture: the cell spec's ``cameras.<id>.settings``, overridden per feature by ``cli``."""
    out = {cid: dict(c.settings) for cid, c in (cell.cameras.items() if cell is not None else []) if c.settings}
    for cid, features in (cli or {}).items():
        out.setdefault(cid, {}).update(features)
    return out
