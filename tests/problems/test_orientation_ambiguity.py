"""A symmetric board seen turned by 180° in some views of a hand-eye cell: the right hand-eye, or exit 3
naming the ambiguity, never a silently wrong one.

The views are labelled exactly as the detector labels a board whose print does not fix its orientation
(:func:`jcalib.vision.orientation.assign_grid_indices`: target +x towards image +u) and carry its
``orientation_ambiguous`` flag, as ``jcalib detect`` writes them.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jcalib
from jcalib.errors import NotObservableError
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.problems.orientation import quarter_turn_permutations, relabel
from jcalib.sim.scene import project_target
from jcalib.vision.orientation import assign_grid_indices

BOARD = Checkerboard(8, 6, 0.025)  # cols + rows even: looks the same turned by 180°
K = np.array([[1000.0, 0.0, 639.5], [0.0, 1000.0, 479.5], [0.0, 0.0, 1.0]])
CAMERA = camera_from_opencv(K, np.zeros(5), (1280, 960))
INTRINSICS = {"model": "opencv5", "intrinsics": {"K": K.tolist(), "dist": [0.0] * 5},
              "fix": ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]}


def _pose(R, t):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _views(rng, n):
    """(n, 4, 4) T_cam_target: cameras 0.4-0.7 m from the board's printed (-z) face, tilted up to 35°,
    rolled anywhere (so that the detector's labelling turns some views by 180°)."""
    c = BOARD.points.mean(axis=0)
    out = []
    for _ in range(n):
        v = Rotation.from_euler("xy", rng.uniform(-35, 35, 2), degrees=True).apply([0.0, 0.0, 1.0])
        centre = c - rng.uniform(0.4, 0.7) * v
        x = np.cross([0.0, 1.0, 0.0], v)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(v, x), v]) @ Rotation.from_euler("z", rng.uniform(-180, 180), degrees=True).as_matrix()
        out.append(np.linalg.inv(_pose(R, centre)))
    return np.array(out)


def _detection(T_cam_target, rng, camera="cam0"):
    """What ``jcalib detect`` records for one view: pixels and the detector's (possibly turned) labels."""
    pix, vis = project_target(CAMERA, T_cam_target, BOARD.points)
    assert vis.all()
    pix = pix + 0.1 * rng.normal(size=pix.shape)
    index, ambiguous = assign_grid_indices(BOARD, pix)  # pixels in the board's own order, labelled by the rule
    assert ambiguous
    return {"camera": camera, "target": "board", "point_index": index.tolist(), "pixels": pix.tolist(),
            "orientation_ambiguous": True}, bool(np.any(index != np.arange(BOARD.num_points)))


def _cell(cameras):
    return {"schema": "jcalib.cell/1", "cameras": cameras, "robot": {},
            "targets": {"board": {**BOARD.to_spec(), "mount": "base"}}}


def _observations(stations, cameras):
    return {"schema": "jcalib.observations/1", "cameras": {c: {"image_size": [1280, 960]} for c in cameras},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}


def _rotation_deg(A, B):
    return float(np.degrees(Rotation.from_matrix(A[:3, :3].T @ B[:3, :3]).magnitude()))


@pytest.mark.parametrize("seed", [0, 1])
def test_eye_in_hand_with_views_turned_by_the_labelling_gives_the_true_hand_eye(seed):
    rng = np.random.default_rng(seed)
    X = _pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.1, 0.1, 3))  # T_flange_cam
    T_base_target = _pose(Rotation.from_euler("z", 30, degrees=True).as_matrix(), [0.7, 0.1, -0.2])
    T_ct = _views(rng, 14)
    stations, turned = [], 0
    for i, T in enumerate(T_ct):
        det, flipped = _detection(T, rng)
        turned += flipped
        T_bf = T_base_target @ np.linalg.inv(T) @ np.linalg.inv(X)
        stations.append({"id": f"s{i:02d}", "T_base_flange": T_bf.tolist(), "detections": [det]})
    assert 3 <= turned <= 11  # the case at hand: some views labelled 180° off, not all
    cell = _cell({"cam0": {**INTRINSICS, "mount": "flange"}})
    # (refusing by name would be allowed too; with this motion the views decide, and the hand-eye is right)
    result = jcalib.calibrate(cell, _observations(stations, ["cam0"]))
    X_est = np.asarray(result.file.transforms["T_flange_cam0"].matrix)
    assert _rotation_deg(X_est, X) < 0.05 and np.linalg.norm(X_est[:3, 3] - X[:3, 3]) < 5e-4
    assert any("turned to agree with the robot motion" in w for w in result.file.stats.get("warnings", []))


def test_board_seen_by_two_cameras_in_ambiguous_views_only_is_refused_by_name():
    """A hand camera and a fixed camera see the symmetric board in every station: each camera's views agree
    with each other, but nothing relates the two cameras' labellings: exit 3 naming it."""
    rng = np.random.default_rng(3)
    X = _pose(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.1, 0.1, 3))
    T_base_target = np.eye(4)
    T_base_fixed = T_base_target @ np.linalg.inv(_views(rng, 1)[0])
    stations = []
    for i, T in enumerate(_views(rng, 10)):
        T_bf = T_base_target @ np.linalg.inv(T) @ np.linalg.inv(X)
        d0, _ = _detection(T, rng, "hand")
        d1, _ = _detection(np.linalg.inv(T_base_fixed) @ T_base_target, rng, "fixed")
        stations.append({"id": f"s{i:02d}", "T_base_flange": T_bf.tolist(), "detections": [d0, d1]})
    cell = _cell({"hand": {**INTRINSICS, "mount": "flange"}, "fixed": {**INTRINSICS, "mount": "base"}})
    with pytest.raises(NotObservableError, match="orientation|labelling") as e:
        jcalib.calibrate(cell, _observations(stations, ["hand", "fixed"]))
    assert "board" in str(e.value)


def test_quarter_turns_of_symmetric_and_unambiguous_boards():
    assert sorted(quarter_turn_permutations(Checkerboard(8, 6, 0.02).points)) == [0, 2]
    assert sorted(quarter_turn_permutations(Checkerboard(9, 6, 0.02).points)) == [0, 2]  # the points are symmetric
    assert sorted(quarter_turn_permutations(Checkerboard(5, 5, 0.02).points)) == [0, 1, 2, 3]
    perm, S = quarter_turn_permutations(BOARD.points)[2]
    np.testing.assert_allclose(BOARD.points[perm], BOARD.points @ S[:3, :3].T + S[:3, 3], atol=1e-12)


def test_relabel_turns_only_the_named_detections():
    from jcalib.io.observations import parse_observations

    rng = np.random.default_rng(5)
    d0, _ = _detection(_views(rng, 1)[0], rng)
    d1, _ = _detection(_views(rng, 1)[0], rng)
    obs = parse_observations(_observations([{"id": "a", "detections": [d0]}, {"id": "b", "detections": [d1]}], ["cam0"]))
    out = relabel(obs, {("b", "cam0", "board"): 2})
    assert out.stations[0].detections[0] == obs.stations[0].detections[0]
    turned = out.stations[1].detections[0]
    perm = quarter_turn_permutations(BOARD.points)[2][0]
    np.testing.assert_array_equal(turned.point_index, perm[obs.stations[1].detections[0].point_index])
    assert not turned.orientation_ambiguous
