"""Per-view board poses ``T_cam_board`` (solvePnP) and the corner ordering of symmetric boards."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Mapping, Sequence

import cv2
import numpy as np

from ..camera import Intrinsics, pixels_from_board_points
from ..errors import CalibrationError
from ..frames import inv_T, make_T, project_to_rotation, rotation_angle_rad, rotvec_from_R, screw_invariants
from ..records import Detection
from ..targets import TargetSpec


def solve_pnp(object_points: np.ndarray, image_points: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, float]:
    """``T_cam_board`` from one view's corners, refined (Levenberg-Marquardt): (T, rms_px).

    ``object_points`` (N,3) board frame, metres; ``image_points`` (N,2) pixels, in the same order.
    """
    obj = object_points.astype(np.float64).reshape(-1, 1, 3)
    img = image_points.astype(np.float64).reshape(-1, 1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, img, intr.K, intr.dist_array, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        ok, rvec, tvec = cv2.solvePnP(obj, img, intr.K, intr.dist_array, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationError("solvePnP failed for a view", code="pnp_failed")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, intr.K, intr.dist_array, rvec, tvec)
    T = make_T(cv2.Rodrigues(rvec)[0], tvec.reshape(3))
    return T, reprojection_rms(object_points, image_points, T, intr)


def refit_pose(
    T_cam_board: np.ndarray, object_points: np.ndarray, image_points: np.ndarray, intr: Intrinsics
) -> np.ndarray:
    """``T_cam_board`` refined (Levenberg-Marquardt) from a start, under intrinsics ``intr``: the nearest pose."""
    obj = object_points.astype(np.float64).reshape(-1, 1, 3)
    img = image_points.astype(np.float64).reshape(-1, 1, 2)
    rvec = cv2.Rodrigues(np.asarray(T_cam_board, float)[:3, :3])[0]
    tvec = np.asarray(T_cam_board, float)[:3, 3].reshape(3, 1).copy()
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, intr.K, intr.dist_array, rvec, tvec)
    return make_T(cv2.Rodrigues(rvec)[0], tvec.reshape(3))


def reprojection_rms(
    object_points: np.ndarray, image_points: np.ndarray, T_cam_board: np.ndarray, intr: Intrinsics
) -> float:
    """RMS (px) of the corner residuals of one view under ``T_cam_board``."""
    r = pixels_from_board_points(T_cam_board, object_points, intr) - image_points
    return float(np.sqrt(np.mean(np.sum(r**2, axis=1))))


@dataclass(frozen=True)
class BoardPose:
    view_id: str
    T_cam_board: np.ndarray
    rms_px: float
    orientation: int  # index into target.symmetries()
    corner_ids: np.ndarray  # ids after resolving the orientation
    candidates: tuple[
        np.ndarray, ...
    ] = ()  # symmetric boards: T_cam_board under every admissible ordering (index = orientation)


def board_poses(
    detections: Sequence[Detection], target: TargetSpec, intr: Intrinsics, M: Mapping[str, np.ndarray]
) -> dict[str, BoardPose]:
    """Per-view ``T_cam_board``, with the corner ordering of symmetric boards made consistent.

    A symmetric board's detector ordering may be turned by 180 (or 90) degrees in some views. For
    each view every admissible ordering is solved; then the combination is chosen whose camera
    motions agree with the robot motions ``M`` (rotation angle and screw pitch of each relative
    motion are invariant under the unknown transforms).

    A target whose pose is ambiguous (``pose_ambiguous``: one square marker) keeps both poses of the
    planar ambiguity (:func:`planar_pose_pair`, the better-fitting first) as its candidates, and the robot
    motions choose between them the same way; ``orientation`` is then the index of the chosen pose.
    """
    obj = target.object_points()
    syms = target.symmetries()
    ambiguous = bool(getattr(target, "pose_ambiguous", False))
    cands: dict[str, list[tuple[np.ndarray, float, np.ndarray]]] = {}
    for d in detections:
        if ambiguous:
            cands[d.view_id] = [
                (T, rms, d.corner_ids) for T, rms in planar_pose_pair(obj[d.corner_ids], d.image_points, intr)
            ]
            continue
        cands[d.view_id] = []
        for perm in syms:
            ids = perm[d.corner_ids]
            T, rms = solve_pnp(obj[ids], d.image_points, intr)
            cands[d.view_id].append((T, rms, ids))
    labels = {vid: 0 for vid in cands}
    many = len(syms) > 1 or ambiguous
    if many and len(cands) >= 2:
        vids = list(cands)
        Cs = np.stack([[c[0] for c in cands[v]] for v in vids])  # (n,k,4,4)
        Ms = np.stack([M[v] for v in vids])
        lab = orientation_labels(candidate_invariants(Cs), Ms, turns=not ambiguous)
        labels = dict(zip(vids, rotation_consistent_labels(Cs, Ms, lab) if ambiguous else lab, strict=False))
    return {
        vid: BoardPose(
            vid,
            cands[vid][c][0],
            cands[vid][c][1],
            c,
            cands[vid][c][2],
            tuple(t[0] for t in cands[vid]) if many else (),
        )
        for vid, c in labels.items()
    }


def planar_pose_pair(
    object_points: np.ndarray, image_points: np.ndarray, intr: Intrinsics
) -> list[tuple[np.ndarray, float]]:
    """Both poses ``[(T_cam_board, rms_px), ...]`` of the planar ambiguity.

    Both poses ``[(T_cam_board, rms_px), ...]`` of the planar ambiguity (IPPE's two solutions, each refined
    with Levenberg-Marquardt), the smaller reprojection error first; one entry when IPPE gives one.
    """
    obj = object_points.astype(np.float64).reshape(-1, 1, 3)
    img = image_points.astype(np.float64).reshape(-1, 1, 2)
    n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, intr.K, intr.dist_array, flags=cv2.SOLVEPNP_IPPE)
    if not n:
        return [solve_pnp(object_points, image_points, intr)]
    out = []
    for rvec, tvec in zip(rvecs, tvecs, strict=False):
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, intr.K, intr.dist_array, rvec, tvec)
        T = make_T(cv2.Rodrigues(rvec)[0], tvec.reshape(3))
        out.append((T, reprojection_rms(object_points, image_points, T, intr)))
    out.sort(key=lambda c: c[1])
    return out if len(out) == 2 else out + out  # always two candidates, so every view has the same count


def rotation_consistent_labels(
    Cs: np.ndarray, Ms: np.ndarray, labels: np.ndarray, *, rounds: int = 5, max_triples: int = 300
) -> np.ndarray:
    """Candidate labels chosen by the rotations of the model ``C_i = A M_i B`` itself (hypothesise and verify).

    The pair invariants of :func:`orientation_labels` compare one number per pair and drown in the pose noise of
    a small marker (the screw pitch especially); a flipped planar pose is 10-40 degrees off the rotation the model
    predicts while the noise is a degree or two. Hypotheses: three views with a choice of candidates each give the
    rotation of A (their pair rotation axes map by R_A, Park and Martin) and of B (chordal mean); every view then
    takes its candidate nearest to the predicted ``R_A R_Mi R_B`` and the hypothesis scores the sum of those angles,
    each capped at 10 degrees so that a wrong robot pose counts as one bad view. The best hypothesis (the start
    ``labels`` is one) is refined with all views until its labels are stable. ``Cs`` (n,k,4,4), ``Ms`` (n,4,4).
    """
    n, k = Cs.shape[:2]
    R_M, R_Cs = Ms[:, :3, :3], Cs[..., :3, :3]
    cap = np.radians(10.0)

    def model(lab: np.ndarray, views: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R_A, R_B) from the views ``views`` with labels ``lab`` (per view of ``views``)."""
        R_C = R_Cs[views, lab]
        p, q = np.triu_indices(len(views), 1)
        a = rotvec_from_R(R_M[views][p] @ np.transpose(R_M[views][q], (0, 2, 1)))
        b = rotvec_from_R(R_C[p] @ np.transpose(R_C[q], (0, 2, 1)))
        R_A = project_to_rotation(b.T @ a)  # the SVD solution of Park and Martin
        R_B = project_to_rotation(np.einsum("nba,nbc->ac", R_A @ R_M[views], R_C))
        return R_A, R_B

    def verify(R_A: np.ndarray, R_B: np.ndarray) -> tuple[np.ndarray, float]:
        ang = _candidate_angles(R_A[None], R_B[None], R_M, R_Cs)[0]
        return np.argmin(ang, axis=1), float(np.minimum(ang.min(axis=1), cap).sum())

    best_lab, best_score = verify(*model(np.asarray(labels, int), np.arange(n)))
    rng = np.random.default_rng(0)
    triples = (
        np.array(list(itertools.combinations(range(n), 3)))
        if n <= 14
        else np.sort(np.array([rng.choice(n, 3, replace=False) for _ in range(max_triples)]), axis=1)
    )
    if len(triples) > max_triples:
        triples = triples[rng.choice(len(triples), max_triples, replace=False)]
    combos = np.array(list(np.ndindex(k, k, k)))
    lab, score = _best_hypothesis(R_M, R_Cs, triples, combos, cap)
    if score < best_score:
        best_lab, best_score = lab, score
    lab = best_lab
    for _ in range(rounds):
        new, _score = verify(*model(lab, np.arange(n)))
        if np.array_equal(new, lab):
            break
        lab = new
    return lab


def _best_hypothesis(
    R_M: np.ndarray, R_Cs: np.ndarray, triples: np.ndarray, combos: np.ndarray, cap: float, *, chunk: int = 256
) -> tuple[np.ndarray, float]:
    """(labels, score) of the first best of the hypotheses of :func:`rotation_consistent_labels`, all at once.

    Every (triple, combo) in that order: R_A from the triple's pair rotation axes under the combo's labels,
    R_B their chordal mean, each view's nearest candidate to ``R_A R_Mi R_B`` and the sum of those angles capped at
    ``cap``; the pair rotation vectors are computed once, the hypotheses in chunks of ``chunk``.
    """
    n, k = R_Cs.shape[:2]
    pairs = np.array([(0, 1), (0, 2), (1, 2)])
    first, second = triples[:, pairs[:, 0]], triples[:, pairs[:, 1]]  # (T,3): each triple's pairs of views
    a = rotvec_from_R(R_M[first] @ np.swapaxes(R_M[second], -1, -2))  # (T,3,3)
    C = R_Cs[first][:, :, :, None] @ np.swapaxes(R_Cs[second], -1, -2)[:, :, None]  # (T,3,k,k,3,3): C_ia C_jb^T
    b_all = rotvec_from_R(C.reshape(-1, 3, 3)).reshape(len(triples), 3, k, k, 3)
    hyp = np.array([(t, c) for t in range(len(triples)) for c in range(len(combos))])
    best_lab, best_score = np.zeros(n, int), np.inf
    for h0 in range(0, len(hyp), chunk):
        t, c = hyp[h0 : h0 + chunk, 0], hyp[h0 : h0 + chunk, 1]
        views, labs = triples[t], combos[c]  # (H,3) each
        b = b_all[t[:, None], np.arange(3)[None], labs[:, pairs[:, 0]], labs[:, pairs[:, 1]]]  # (H,3,3)
        R_A = project_to_rotation(np.swapaxes(b, -1, -2) @ a[t])  # the SVD solution of Park and Martin
        R_C = R_Cs[views, labs]  # (H,3,3,3)
        R_B = project_to_rotation(np.einsum("hnba,hnbc->hac", R_A[:, None] @ R_M[views], R_C))
        ang = _candidate_angles(R_A, R_B, R_M, R_Cs)
        score = np.minimum(ang.min(axis=2), cap).sum(axis=1)
        i = int(np.argmin(score))
        if score[i] < best_score:
            best_lab, best_score = np.argmin(ang[i], axis=1), float(score[i])
    return best_lab, best_score


def _candidate_angles(R_A: np.ndarray, R_B: np.ndarray, R_M: np.ndarray, R_Cs: np.ndarray) -> np.ndarray:
    """(H, n, k): the angle (rad) of each view's candidates ``R_Cs`` (n,k,3,3) from ``R_A R_Mi R_B``, per hypothesis.

    ``R_A``, ``R_B`` (H,3,3): the hypotheses; ``R_M`` (n,3,3) the robot motions' rotations.
    """
    pred = R_A[:, None] @ R_M[None] @ R_B[:, None]  # (H,n,3,3)
    H, (n, k) = len(R_A), R_Cs.shape[:2]
    return rotation_angle_rad(np.einsum("hnba,nkbc->hnkac", pred, R_Cs).reshape(-1, 3, 3)).reshape(H, n, k)


def candidate_invariants(Cs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Screw invariants (angle, pitch) of the camera pair motions for every ordering of each view.

    Screw invariants (angle, pitch), each (n,k,n,k), of the camera pair motions for every ordering of
    each view: ``Cs`` (n,k,4,4) is ``T_cam_board`` of view i under ordering a.
    """
    n, k = Cs.shape[:2]
    rel_C = Cs[:, :, None, None] @ inv_T(Cs)[None, None]  # (n,k,n,k,4,4)
    ang_C, pitch_C = screw_invariants(rel_C.reshape(-1, 4, 4))
    return ang_C.reshape(n, k, n, k), pitch_C.reshape(n, k, n, k)


def orientation_labels(inv_C: tuple[np.ndarray, np.ndarray], Ms: np.ndarray, *, turns: bool = True) -> np.ndarray:
    """The symmetry candidate of each view whose camera motions agree best with the robot motions.

    The candidate (index into the target's symmetries) of each view whose camera motions agree best with
    the robot motions ``Ms`` (n,4,4); ``inv_C`` from :func:`candidate_invariants`. With ``turns`` (the
    candidates are turns of a symmetric board) the detector's own order is kept for the majority (turning
    every view alike only changes the board frame); without (the two poses of a planar ambiguity) the
    labels are kept as they are.
    """
    ang_C, pitch_C = inv_C
    n, k = ang_C.shape[:2]
    # robot relative-motion invariants for all pairs
    rel_M = Ms[:, None] @ inv_T(Ms)[None, :]  # (n,n,4,4) M_i M_j^-1
    ang_M, pitch_M = screw_invariants(rel_M.reshape(-1, 4, 4))
    # cost[i,a,j,b]: disagreement when view i uses ordering a and view j ordering b
    am = ang_M.reshape(n, 1, n, 1)
    pm = pitch_M.reshape(n, 1, n, 1)
    # pitch's sign follows the axis direction, which is defined consistently by the rotation vector;
    # 0.1 m of pitch weighs like 1 rad of angle
    cost = np.abs(ang_C - am) + np.abs(pitch_C - pm) / 0.1
    cost[np.arange(n), :, np.arange(n), :] = 0.0  # a view is not compared with itself
    idx = np.arange(n)
    # rows[i][j*k + b, a] = cost[i, a, j, b]: a view's costs against the current labels are one gather of
    # contiguous rows, summed over j in order (the sum of cost[i][:, idx, lab] over j, to the bit)
    rows = np.ascontiguousarray(cost.transpose(0, 2, 3, 1)).reshape(n, n * k, k)
    # one start per view r (view r's ordering 0, the others' best against it), the distinct ones in order:
    # every start runs its rounds side by side with the others, each start's views updated one at a time
    starts = np.argmin(cost[:, :, :, 0], axis=1).T  # (n starts, n views)
    starts[idx, idx] = 0
    _, first = np.unique(starts, axis=0, return_index=True)
    labs = starts[np.sort(first)]  # (S, n)
    cols = idx * k + labs  # the rows of rows[i] under each start's current labels
    for _ in range(3):  # a few rounds of iterated conditional modes
        before = labs.copy()
        for i in range(n):
            a = np.add.reduce(rows[i][cols], axis=1).argmin(axis=1)  # (S,): each start's ordering of view i
            labs[:, i], cols[:, i] = a, i * k + a
        if np.array_equal(labs, before):  # a round that changes nothing is a fixed point for every start
            break
    best, best_cost = None, np.inf
    for lab in labs:
        c = cost[idx[:, None], lab[:, None], idx[None, :], lab[None, :]].sum()
        if c < best_cost:
            best, best_cost = lab.copy(), c
    assert best is not None, "no labelling with a finite cost"
    return (_majority_frame(best, k) if turns else best).astype(int)


def _majority_frame(labels: np.ndarray, k: int) -> np.ndarray:
    """Re-express consistent orientation labels so that the detector's own order is the majority.

    Turning every view by the same symmetry is a change of the board frame only; choose the one
    that keeps most views as detected (so an asymmetric board keeps OpenCV's origin). Labels index
    ``ChessboardSpec.symmetries()``: turns of 0, 180, 90, 270 degrees.
    """
    turns = np.array([0, 2, 1, 3])[:k] if k in (2, 4) else None
    if turns is None:
        return labels
    q = turns[labels]
    shift = np.bincount(q, minlength=4).argmax()
    q = (q - shift) % 4
    back = {t: i for i, t in enumerate(turns)}
    return np.array([back[t] for t in q])
