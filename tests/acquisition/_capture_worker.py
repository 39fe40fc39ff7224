"""Capture worker for the kill -9 test: runs (or resumes) a simulated capture into argv[1].

Every station start is logged to argv[2] with one write(2) on an O_APPEND descriptor, so the log is
in the kernel before the process can be killed. The image of a station encodes the true flange
position (0.01 mm units) in its first row, so the test can check that an image belongs to its pose.
"""

import os
import sys

import numpy as np

from jcalib.acquisition import capture
from jcalib.io.plan import make_plan
from jcalib.acquisition.cameras import SimulatedCamera
from jcalib.acquisition.robots import SimulatedController, SimulatedRobot

NUM_STATIONS = 40


def plan_poses(T0):
    poses = []
    for i in range(NUM_STATIONS):
        T = T0.copy()
        T[:3, 3] += [0.004 * (i % 10), 0.01 * (i // 10), -0.002 * (i % 7)]
        poses.append(T)
    return poses


def main():
    session, log = sys.argv[1], sys.argv[2]
    ctrl = SimulatedController(time_scale=0.2, seed=os.getpid())
    robot = SimulatedRobot(ctrl)

    def source(req):
        img = np.full((req.height, req.width), 90, np.uint8)
        code = np.round(ctrl.true_T_base_flange()[:3, 3] * 1e5).astype("<i4")
        img[0, :12] = np.frombuffer(code.tobytes(), np.uint8)
        img[1:, :] = np.arange(req.width, dtype=np.uint8)[None, :]
        return img

    cams = {"cam0": SimulatedCamera(source, name="cam0", sensor_size=(64, 48)),
            "cam1": SimulatedCamera(source, name="cam1", sensor_size=(32, 24))}
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    T0 = SimulatedRobot(SimulatedController(time_scale=0.0)).state().T_base_flange

    def listener(event, sid, detail):
        if event == "start":
            os.write(fd, f"{os.getpid()} start {sid}\n".encode())

    resume = os.path.exists(os.path.join(session, "session.json"))
    capture(make_plan(plan_poses(T0)), robot, cams, session, resume=resume, progress=False, listener=listener)
    os.write(fd, f"{os.getpid()} finished\n".encode())


if __name__ == "__main__":
    main()
