"""Board labellings left open by the board's symmetry, resolved from the robot motion (or refused by name).

A chessboard with ``cols + rows`` even or a symmetric circle grid looks the same turned by 180° (a square
one by 90°): its detector labels such a view by a convention (:mod:`jcalib.vision.orientation`) and marks
it ``orientation_ambiguous``. In a camera-only calibration each view has its own target pose, which absorbs
any labelling; but where one target pose is shared by many stations (a hand-eye cell, a fixed camera and a
fixed board) a view labelled 180° off is a wrong pose, which the closed-form start and the outlier rounds
may or may not catch. Before the start, every camera-target pair whose views carry the flag is therefore
relabelled so that its views agree with each other:

- a pair the robot moves (camera on the flange and target fixed, or the reverse): the motion of the
  camera relative to the target between two stations, ``B``, and the robot's, ``A``, satisfy
  ``A X = X B``, so their rotation angles and their translations along the rotation axis are equal
  whatever ``X`` is (screw invariants). For two views the relative labelling (0, 90, 180 or 270° of the
  board's symmetry) whose ``B`` matches ``A`` best is taken when it matches within the noise and the others
  clearly do not;
- a pair that does not move (both fixed, or both on one flange): the camera-target pose is the same at
  every station; the relative labelling that makes two views' poses agree is taken.

Views are then labelled outward from the unambiguous views (or, when every view is ambiguous, from the
best-connected one: turning every view of one camera-target pair alike only moves the target frame, which
its pose absorbs), each by the majority of its decided relations. A view no relation decides, or a target
whose views are all ambiguous but seen by several cameras (nothing relates their conventions), raises
:class:`~jcalib.errors.NotObservableError` naming the stations: exit 3, never a silently flipped pose.
Free targets seen by one camera per station need nothing (each view has its own pose); free targets seen
by several cameras at once are left as the detector labelled them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from jcalib.errors import NotObservableError
from jcalib.geometry.se3 import invert, rotvec
from jcalib.problems.graph import FREE

__all__ = ["quarter_turn_permutations", "relabel", "resolve_orientations"]

#: Noise scales of the screw invariants (rotation angle, translation along the axis) of a view pair.
SIGMA_ANGLE_DEG = 1.0
SIGMA_ALONG_M = 0.003
#: A relation is decided when its best labelling matches within this many noise scales and every other
#: labelling misses by at least this many more.
DECIDED = 8.0


def quarter_turn_permutations(points: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The board's proper symmetries: quarter turns ``q`` -> ``(perm, S)`` with
    ``points[perm] == S @ points`` (``S`` (4, 4), a rotation by ``q * 90°`` about the board's centre in its
    plane, target frame); always holds ``q = 0``."""
    p = np.asarray(points, np.float64)
    c = p[:, :2].mean(axis=0)
    scale = float(np.max(np.ptp(p[:, :2], axis=0))) or 1.0
    out = {}
    for q in range(4):
        a = q * np.pi / 2
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]).round(12)
        moved = (p[:, :2] - c) @ R.T + c
        d = np.linalg.norm(moved[:, None, :] - p[None, :, :2], axis=-1)
        perm = np.argmin(d, axis=1)
        if np.all(d[np.arange(len(p)), perm] < 1e-9 * scale) and len(np.unique(perm)) == len(p) \
                and np.allclose(p[perm, 2], p[:, 2]):
            S = np.eye(4)
            S[:2, :2] = R
            S[:2, 3] = c - R @ c
            out[q] = (perm.astype(np.int64), S)
    return out


def _screw(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K,) rotation angles (rad) and (K,) translations along the rotation axis of motions (K, 4, 4)."""
    w = rotvec(T[:, :3, :3])
    angle = np.linalg.norm(w, axis=-1)
    axis = w / np.maximum(angle, 1e-12)[:, None]
    along = np.einsum("ki,ki->k", T[:, :3, 3], axis)
    return angle, np.where(angle > 1e-6, np.abs(along), np.linalg.norm(T[:, :3, 3], axis=-1))


def _relations(kind: str, H: np.ndarray, P: np.ndarray, turns: dict) -> tuple[np.ndarray, np.ndarray]:
    """For every view pair (j, k): the relative quarter turns of view k that fit best, and whether that
    is decided. ``H`` (N, 4, 4) the robot holder's poses (``kind`` "hand": camera on it; "eye": target on
    it; "static": unused), ``P`` (N, 4, 4) camera-target poses with the detector's labels."""
    n = len(P)
    j, k = np.triu_indices(n, 1)
    errors = []
    qs = sorted(turns)
    for q in qs:
        Pk = P[k] @ invert(turns[q][1])[None]  # view k relabelled by q quarter turns
        if kind == "static":
            D = invert(P[j]) @ Pk
            angle, along = _screw(D)
            e = np.degrees(angle) / SIGMA_ANGLE_DEG + np.linalg.norm(D[:, :3, 3], axis=-1) / SIGMA_ALONG_M
        else:
            A = invert(H[k]) @ H[j]
            B = Pk @ invert(P[j]) if kind == "hand" else invert(Pk) @ P[j]
            (ta, da), (tb, db) = _screw(A), _screw(B)
            e = np.degrees(np.abs(ta - tb)) / SIGMA_ANGLE_DEG + np.abs(da - db) / SIGMA_ALONG_M
        errors.append(e)
    E = np.stack(errors, axis=1)  # (pairs, turns)
    order = np.argsort(E, axis=1)
    best = E[np.arange(len(E)), order[:, 0]]
    second = E[np.arange(len(E)), order[:, 1]] if E.shape[1] > 1 else np.full(len(E), np.inf)
    rel = np.full((n, n), -1)
    ok = np.zeros((n, n), bool)
    qbest = np.array(qs)[order[:, 0]]
    decided = (best < DECIDED) & (second > best + DECIDED)
    rel[j, k], rel[k, j] = qbest, (-qbest) % 4
    ok[j, k] = ok[k, j] = decided
    return rel, ok


def _assign(rel: np.ndarray, ok: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """Quarter turns per view from decided relations, outward from the anchors (-1: undecided)."""
    n = len(rel)
    q = np.full(n, -1)
    if anchors.any():
        q[anchors] = 0
    elif n:
        q[int(np.argmax(ok.sum(axis=1)))] = 0
    while True:
        todo = [v for v in range(n) if q[v] < 0 and np.any(ok[v] & (q >= 0))]
        if not todo:
            return q
        v = max(todo, key=lambda v: int(np.sum(ok[v] & (q >= 0))))
        votes = np.bincount((q[ok[v] & (q >= 0)] + rel[ok[v] & (q >= 0), v]) % 4, minlength=4)
        q[v] = int(np.argmax(votes))


def resolve_orientations(g, views: dict) -> tuple[dict[tuple[str, str, str], int], list[str]]:
    """Quarter turns that relabel the ambiguous detections consistently (see the module docstring).

    Args:
        g: the cell's :class:`~jcalib.problems.graph.Graph`.
        views: ``(camera, target)`` -> station index -> ``T_cam_target`` (4, 4) from the detector's labels
            (:attr:`jcalib.problems.start.Start.views`).

    Returns:
        ``({(station id, camera, target): quarter turns}, warnings)`` for the detections to relabel.

    Raises:
        NotObservableError: views whose labelling neither the motion nor the other views decide.
    """
    flagged = {}
    for st in g.obs.stations:
        for d in st.detections:
            if d.target is not None and d.orientation_ambiguous:
                flagged[(st.id, d.camera, d.target)] = True
    if not flagged:
        return {}, []
    out: dict[tuple[str, str, str], int] = {}
    notes: list[str] = []
    by_target: dict[str, list[tuple[str, str]]] = {}
    for key in g.pairs:
        by_target.setdefault(key[1], []).append(key)
    for target, keys in by_target.items():
        spec = g.cell.targets[target]
        ht = g.holder(spec)
        amb_keys = [key for key in keys if any((g.station_ids[k], key[0], target) in flagged for k in g.pairs[key].views)]
        if not amb_keys or ht == FREE:
            continue
        turns = quarter_turn_permutations(g.obs.targets[target])
        unanchored = []
        for key in keys:
            cam = key[0]
            hc = g.holder(g.cell.cameras[cam])
            ks = list(g.pairs[key].views)
            amb = np.array([(g.station_ids[k], cam, target) in flagged for k in ks])
            if not amb.any():
                continue
            if hc == FREE:
                continue
            if hc == ht:
                kind, H = "static", None
            elif ht is None:
                kind, H = "hand", g.flange[hc][ks]
            elif hc is None:
                kind, H = "eye", g.flange[ht][ks]
            else:
                raise NotObservableError(
                    f"target '{target}' looks the same turned by {360 // len(turns)}° and camera '{cam}' and the "
                    "target ride on two robots: jcalib cannot tell from the motion which way round the ambiguous "
                    "views saw it; use a board whose print fixes its orientation (cols + rows odd, ChArUco, a "
                    "circle grid with an origin dot)", [f"orientation of {target} in {cam}'s views"])
            P = np.stack([views[key][k] for k in ks])
            rel, ok = _relations(kind, H, P, turns)
            q = _assign(rel, ok, ~amb)
            undecided = [g.station_ids[ks[i]] for i in np.flatnonzero(q < 0)]
            if undecided:
                shown = ", ".join(undecided[:6]) + ("..." if len(undecided) > 6 else "")
                raise NotObservableError(
                    f"target '{target}' looks the same turned by {360 // len(turns)}° and camera '{cam}' saw it at "
                    f"stations {shown} in an orientation that neither the robot motion nor the other views decide: "
                    "their point labels may be turned. Use a board whose print fixes its orientation (cols + rows "
                    "odd, ChArUco, a circle grid with an origin dot), or leave these stations out",
                    [f"orientation of {target} at {s} ({cam})" for s in undecided])
            if not (~amb).any():
                unanchored.append(cam)
            for i, k in enumerate(ks):
                if amb[i] and q[i] != 0:
                    out[(g.station_ids[k], cam, target)] = int(q[i])
            flipped = [g.station_ids[ks[i]] for i in range(len(ks)) if amb[i] and q[i] != 0]
            if flipped:
                notes.append(f"target '{target}' (symmetric print): {len(flipped)} of camera '{cam}''s views turned "
                             f"to agree with the robot motion and the other views ({', '.join(flipped[:6])}"
                             f"{'...' if len(flipped) > 6 else ''})")
        if unanchored and len([k for k in keys if g.holder(g.cell.cameras[k[0]]) != FREE]) > 1:
            raise NotObservableError(
                f"target '{target}' looks the same turned by {360 // len(turns)}° in every view of camera(s) "
                f"{', '.join(repr(c) for c in unanchored)}, and other cameras see it too: nothing relates the cameras' "
                "labellings of the board. Use a board whose print fixes its orientation (cols + rows odd, ChArUco, a "
                "circle grid with an origin dot)", [f"orientation of {target} between cameras"])
    return out, notes


def relabel(obs, turns: dict[tuple[str, str, str], int]):
    """``obs`` with the detections of ``turns`` ((station, camera, target) -> quarter turns) relabelled by
    the board's symmetry (no longer ambiguous: the resolution decided them)."""
    if not turns:
        return obs
    perms = {t: quarter_turn_permutations(P) for t, P in obs.targets.items() if any(k[2] == t for k in turns)}
    stations = []
    for st in obs.stations:
        dets = []
        for d in st.detections:
            q = turns.get((st.id, d.camera, d.target))
            if q:
                perm = perms[d.target][q][0]
                d = replace(d, point_index=perm[d.point_index], orientation_ambiguous=False)
            dets.append(d)
        stations.append(replace(st, detections=tuple(dets)))
    return replace(obs, stations=tuple(stations))
