"""GigE Vision through Aravis against Aravis' own GigE fake camera serving our frames on loopback."""

from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from jcalib.acquisition.cameras import FakeGigECamera, GigECamera, UnsupportedFeatureError
from jcalib.errors import BadInputError, DeviceError

W, H = 320, 240
SCENE = np.random.default_rng(7).integers(0, 256, (H, W), dtype=np.uint8)


@pytest.fixture(scope="module")
def rig(aravis):
    fake = FakeGigECamera(lambda req: SCENE, "127.0.0.1", sensor_size=(W, H)).start()
    cam = GigECamera("127.0.0.1", name="cam0", packet_size=1400, max_retries=30)
    yield fake, cam
    cam.close()
    fake.stop()


def test_frames_arrive_bit_identical(rig):
    fake, cam = rig
    for _ in range(3):
        f = cam.grab()
        assert f.image.dtype == np.uint8 and f.image.shape == (H, W)
        np.testing.assert_array_equal(f.image, SCENE)  # reference: the frame the source produced
    cam.set_roi(16, 8, 128, 96)
    np.testing.assert_array_equal(cam.grab().image, SCENE[8:104, 16:144])
    cam.set("PixelFormat", "Mono16")
    f = cam.grab()
    assert f.image.dtype == np.uint16 and f.pixel_format == "Mono16"
    np.testing.assert_array_equal(f.image, SCENE[8:104, 16:144].astype(np.uint16) * 257)
    cam.set("PixelFormat", "Mono8")
    cam.set_roi(0, 0, W, H)
    np.testing.assert_array_equal(cam.grab().image, SCENE)
    assert not fake.source_errors


def test_features_and_unsupported_ones(rig):
    _, cam = rig
    cam.set("ExposureTime", 2500.0)  # maps to the fake's ExposureTimeAbs (us)
    assert cam.get("ExposureTime") == pytest.approx(2500.0)
    cam.set("Gain", 3)
    assert cam.get("Gain") == 3
    cam.set("PacketSize", 4000)
    assert cam.get("PacketSize") == 4000
    np.testing.assert_array_equal(cam.grab().image, SCENE)
    cam.set("PacketSize", 1400)
    for lens in ("Zoom", "Focus", "Iris"):
        assert not cam.has(lens)
        with pytest.raises(UnsupportedFeatureError, match=lens):
            cam.get(lens)
        with pytest.raises(DeviceError, match="does not support"):
            cam.set(lens, 1.0)
    with pytest.raises(BadInputError, match="Width must be in 1..320"):
        cam.set("Width", 5000)


def test_packet_loss_never_yields_a_corrupt_frame(rig):
    fake, cam = rig
    before = (cam.stats.incomplete, cam.stats.timeouts, cam.stats.retries)
    fake.set_loss_ratio(0.004)  # ~60 packets per frame at 1400 bytes: ~20 % of frames hit
    try:
        # at least 20 grabs, and on until the loss has hit a frame: P(no hit in 100) = 0.79^100 ~ 1e-10.
        # A hit frame shows as incomplete or, when the lost packet is the trailer, as a timeout
        # (both under load); either way it is retried and never returned.
        for i in range(100):
            np.testing.assert_array_equal(cam.grab(timeout_s=0.5).image, SCENE)
            if i >= 19 and cam.stats.retries > before[2]:
                break
    finally:
        fake.set_loss_ratio(0.0)
    hit = (cam.stats.incomplete - before[0]) + (cam.stats.timeouts - before[1])
    assert hit > 0
    assert cam.stats.retries - before[2] >= hit


def test_total_loss_is_a_clean_device_error_then_recovers(rig):
    fake, cam = rig
    fake.set_loss_ratio(1.0)
    old = cam.max_retries
    cam.max_retries = 1
    try:
        with pytest.raises(DeviceError, match="no complete frame after 2 triggers"):
            cam.grab(timeout_s=0.3)
    finally:
        fake.set_loss_ratio(0.0)
        cam.max_retries = old
    np.testing.assert_array_equal(cam.grab().image, SCENE)


def test_cameras_are_opened_by_address_only(aravis):
    with pytest.raises(BadInputError, match="IPv4 address"):
        GigECamera("cam0.local")
    with pytest.raises(BadInputError, match="IPv4 address"):
        GigECamera("")


def test_capture_with_packet_loss_stores_only_complete_frames(rig, tmp_path):
    from jcalib.acquisition import capture
    from jcalib.io.plan import make_plan
    from jcalib.io.session import read_session
    from jcalib.acquisition.robots import SimulatedController, SimulatedRobot

    import cv2

    fake, cam = rig
    robot = SimulatedRobot(SimulatedController(time_scale=0.0))
    T0 = robot.state().T_base_flange
    poses = [T0 @ np.diag([1.0, 1.0, 1.0, 1.0]) for _ in range(4)]
    for i, T in enumerate(poses):
        T[0, 3] += 0.01 * i
    fake.set_loss_ratio(0.004)
    try:
        capture(make_plan(poses), robot, {"cam0": cam}, tmp_path / "s", progress=False, grab_timeout_s=0.5)
    finally:
        fake.set_loss_ratio(0.0)
    _, stations = read_session(tmp_path / "s")
    assert [s["status"] for s in stations] == ["ok"] * 4
    for s in stations:
        img = cv2.imread(str(tmp_path / "s" / s["images"]["cam0"]), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(img, SCENE)


TWO_CAMERAS = textwrap.dedent(
    """
    import numpy as np
    from jcalib.acquisition.cameras import FakeGigECamera, GigECamera
    a = np.full((48, 64), 11, np.uint8); b = np.full((48, 64), 222, np.uint8)
    with FakeGigECamera(lambda r: a, "127.0.0.1", sensor_size=(64, 48)), \\
         FakeGigECamera(lambda r: b, "127.0.0.2", sensor_size=(64, 48), serial="B"):
        c1 = GigECamera("127.0.0.1", name="cam0"); c2 = GigECamera("127.0.0.2", name="cam1")
        for _ in range(2):
            assert np.array_equal(c1.grab().image, a) and np.array_equal(c2.grab().image, b)
        c1.close(); c2.close()
    print("TWO-CAMERAS-OK")
    """
)


def test_two_fake_cameras_in_a_private_network_namespace(aravis):
    """127.0.0.2 must be an address of lo for the fake to bind: add it inside ``unshare -n``."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        pytest.skip("needs util-linux unshare and iproute2 ip to build a private network namespace")
    probe = subprocess.run(["unshare", "-n", "true"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"cannot create a network namespace here (needs CAP_SYS_ADMIN): {probe.stderr.decode().strip()}")
    cmd = (
        "ip link set lo up && ip addr add 127.0.0.2/8 dev lo && "
        f"exec {sys.executable} -c \"$JCALIB_SCRIPT\""
    )
    r = subprocess.run(
        ["unshare", "-n", "sh", "-c", cmd], capture_output=True, text=True, timeout=120,
        env={**__import__("os").environ, "JCALIB_SCRIPT": TWO_CAMERAS},
    )  # fmt: skip
    assert "TWO-CAMERAS-OK" in r.stdout, r.stdout + r.stderr
