"""Pairing of images and robot poses: shifted by a few lines, shuffled, or single poses swapped.

A single pose may belong to another view (two detected views swapped, or an image carrying an
undetected view's pose). A constant shift reports the code ``pairs_shifted`` (with the shift); a
shuffle, swapped poses and an image carrying another view's pose report ``pairs_shuffled``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Optional, Sequence

import numpy as np

from ..conventions import PoseFormat
from .consistency import RobotPoseCheck, split_candidates
from .findings import Finding
from .fits import fit_boards
from .observations import PoseObservations
from .readings import is_clearly_better, pair_angles_deg, read_poses
from .thresholds import thresholds


def _shifted(obs: PoseObservations, fmt: PoseFormat, shift: int) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(views kept (bool N), T (K,4,4)) when the image at sequence position p takes the pose at p+shift."""
    order = obs.raw.order
    pos = {v: k for k, v in enumerate(order)}
    keep = np.array([v in pos and 0 <= pos[v] + shift < len(order) for v in obs.ids])
    keys = [order[pos[v] + shift] for v, k in zip(obs.ids, keep, strict=False) if k]
    return keep, read_poses(obs.raw, fmt, keys)


def _ordered_for(obs: PoseObservations, keep: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Board poses of the views ``keep``, a symmetric board's ordering resolved for this pairing.

    Board poses of the views ``keep`` with a symmetric board's corner ordering resolved against the robot
    motions ``M`` of this pairing (its own best ordering: a wrong pairing cannot hide behind turned views,
    and a right one is not spoiled by the ordering the wrong pairing chose).
    """
    if obs.C_candidates is None:
        return obs.C[keep]
    from ..initial.board_poses import candidate_invariants, orientation_labels

    cands = obs.C_candidates[keep]
    lab = orientation_labels(candidate_invariants(cands), M, turns=obs.candidates_are_turns)
    return cands[np.arange(len(cands)), lab]


def _fit_pairing(obs: PoseObservations, keep: np.ndarray, T: np.ndarray, invert: bool):
    """The board fit of the views ``keep`` paired with the robot poses ``T``.

    The board fit of the views ``keep`` paired with the robot poses ``T`` (a symmetric board ordered for this
    pairing), or None when it is singular.
    """
    M = obs.M(T, invert=invert)
    try:
        return fit_boards(_ordered_for(obs, keep, M), M)
    except np.linalg.LinAlgError:
        return None


def signature_costs(sig_c: np.ndarray, sig_m: np.ndarray) -> np.ndarray:
    """(N, P) mean distance from each value of the sorted row ``sig_c[i]`` to the nearest one of ``sig_m[p]``.

    ``sig_c`` (N, K) and ``sig_m`` (P, L) have sorted rows. One binary search per value and row (O(N P K log
    L), one numpy pass per ``p``) instead of all K x L differences per (i, p): a 300-view session took 12 s.
    """
    cost = np.empty((len(sig_c), len(sig_m)))
    for p, row in enumerate(sig_m):
        k = np.searchsorted(row, sig_c)  # shape (N, K): the first value of row >= each camera angle
        below = row[np.maximum(k - 1, 0)]
        above = row[np.minimum(k, len(row) - 1)]
        cost[:, p] = np.mean(np.minimum(np.abs(sig_c - below), np.abs(sig_c - above)), axis=1)
    return cost


def _assignment_by_signature(obs: PoseObservations, fmt: PoseFormat, invert: bool) -> Optional[dict]:
    """Match images to poses by their sorted pair-rotation-angle signatures (a shuffled poses file).

    Returns view id -> pose key, or None. Angles of relative motions do not depend on A or B, so the
    sorted list of a view's angles to all others identifies its pose up to noise.
    """
    from scipy.optimize import linear_sum_assignment

    order = list(obs.raw.order)
    T_all = read_poses(obs.raw, fmt, order)
    if T_all is None or obs.n < 5:
        return None
    M_all = obs.M(T_all, invert=invert)

    def angles(R):  # (K,K) rotation angle of R_a R_b^T
        i, j = np.meshgrid(np.arange(len(R)), np.arange(len(R)), indexing="ij")
        return pair_angles_deg(R, i.ravel(), j.ravel()).reshape(len(R), len(R))

    A_c, A_m = angles(obs.C[:, :3, :3]), angles(M_all[:, :3, :3])
    sig_c = np.stack([np.sort(np.delete(A_c[i], i)) for i in range(obs.n)])  # shape (N, N - 1)
    sig_m = np.stack([np.sort(np.delete(A_m[p], p)) for p in range(len(order))])  # shape (P, P - 1)
    # every camera angle must appear among the pose's angles (poses may have more views)
    r, c = linear_sum_assignment(signature_costs(sig_c, sig_m))
    return {obs.ids[i]: order[p] for i, p in zip(r, c, strict=False)}


def _same_values(a: dict, b: dict) -> bool:
    """The same pose numbers for the same views (numbers that do not parse are never the same)."""
    if a.keys() != b.keys():
        return False
    try:
        return all(np.array_equal(np.asarray(a[k], float), np.asarray(b[k], float)) for k in a)
    except (TypeError, ValueError):
        return False


class PairingSearch:
    """The search for the pairing of images and poses that fits better than the given one.

    The search for the pairing of images and poses that fits better than the given one, on one set of
    observations: the best constant shift, and the match of a shuffle by rotation-angle signatures. Each
    part is computed the first time it is asked for and kept, so the pipeline's pairing gate and the
    diagnostics search once (:attr:`handeye.pipeline.CalibrationRun.pairing`); the decision, which depends
    on the cost of the pairing as given, is :func:`pairing_findings`'.
    """

    def __init__(self, obs: PoseObservations, fmt: PoseFormat, *, invert: bool = False):
        self.obs, self.fmt, self.invert = obs, fmt, bool(invert)
        self._shift: Optional[tuple[Any, ...]] = None
        self._shuffle: Optional[tuple[Any, ...]] = None
        self._partial: Optional[tuple[Any, ...]] = None
        self._searched: set[str] = set()

    def matches(self, obs: PoseObservations, fmt: PoseFormat, *, invert: bool = False) -> bool:
        """Whether this search is the one of ``obs`` read with ``fmt``.

        Whether this search is the one of ``obs`` read with ``fmt`` (the same views, board poses, pose
        numbers and file order: everything the search reads).
        """
        a, b = self.obs, obs
        if a is b:
            return self.fmt == fmt and self.invert == bool(invert)
        same_cands = (a.C_candidates is None and b.C_candidates is None) or (
            a.C_candidates is not None and b.C_candidates is not None and np.array_equal(a.C_candidates, b.C_candidates)
        )
        return (
            self.fmt == fmt
            and self.invert == bool(invert)
            and a.mode == b.mode
            and tuple(a.ids) == tuple(b.ids)
            and np.array_equal(a.C, b.C)
            and same_cands
            and a.candidates_are_turns == b.candidates_are_turns
            and tuple(a.raw.order) == tuple(b.raw.order)
            and _same_values(a.raw.values, b.raw.values)
        )

    def best_shift(self) -> Optional[tuple]:
        """(shift, fit, views kept) of the constant shift by +-1..max_shift whose boards fit best, or None."""
        if "shift" not in self._searched:
            self._shift = self._search_shift()
            self._searched.add("shift")
        return self._shift

    def best_partial(self) -> Optional[tuple]:
        """The pairing shifted by one line from one image on whose boards fit best, or None.

        (s, first, lone, fit, keep, keys) of the pairing that is the given one up to an image and shifted by one
        line from there on, whose boards fit best (see :func:`_search_partial`), or None.
        """
        if "partial" not in self._searched:
            self._partial = _search_partial(self.obs, self.fmt, self.invert)
            self._searched.add("partial")
        return self._partial

    def shuffle(self) -> Optional[tuple]:
        """(view id -> pose key, T (N,4,4), C (N,4,4), fit) of the shuffle matched by signature.

        (view id -> pose key, T (N,4,4), C (N,4,4), fit) of the shuffle matched by signature, or None when
        no match moves two or more views.
        """
        if "shuffle" not in self._searched:
            self._shuffle = self._search_shuffle()
            self._searched.add("shuffle")
        return self._shuffle

    def _search_shift(self) -> Optional[tuple]:
        obs, fmt, invert = self.obs, self.fmt, self.invert
        th = thresholds()
        kmax = min(th.pairing.max_shift, max(1, len(obs.raw.order) // 3))
        best = None
        for s in range(-kmax, kmax + 1):
            if s == 0:
                continue
            keep, T = _shifted(obs, fmt, s)
            if T is None or keep.sum() < max(4, int(np.ceil(th.pairing.min_shift_share * obs.n))):
                continue
            fit = _fit_pairing(obs, keep, T, invert)
            if fit is None:
                continue
            if best is None or fit.cost < best[1].cost:
                best = (s, fit, keep)
        return best

    def _search_shuffle(self) -> Optional[tuple]:
        obs, fmt, invert = self.obs, self.fmt, self.invert
        assign = _assignment_by_signature(obs, fmt, invert)
        if assign is None:
            return None
        T = read_poses(obs.raw, fmt, [assign[v] for v in obs.ids])
        C = obs.C
        everything = np.ones(obs.n, bool)
        for _ in range(2 if obs.C_candidates is not None and T is not None else 0):
            # a symmetric board's ordering was chosen for the wrong pairing: re-order for this one and match again
            C = _ordered_for(obs, everything, obs.M(T, invert=invert))
            again = _assignment_by_signature(replace(obs, C=C), fmt, invert)
            T_again = None if again is None else read_poses(obs.raw, fmt, [again[v] for v in obs.ids])
            if T_again is None or again == assign:
                break
            assert again is not None, "T_again read from it"
            assign, T = again, T_again
            C = _ordered_for(obs, everything, obs.M(T, invert=invert))
        moved = [v for v in obs.ids if assign[v] != v]
        if T is None or len(moved) < 2:
            return None
        return assign, T, C, fit_boards(C, obs.M(T, invert=invert))


def _cost_text() -> str:
    th = thresholds().readings
    return f"cost: the median board scatter in units of {th.cost_deg:g} deg and {th.cost_mm:g} mm, combined"


def pairing_findings(
    obs: PoseObservations,
    fmt: PoseFormat,
    *,
    invert: bool = False,
    given_cost: float,
    search: Optional[PairingSearch] = None,
) -> list:
    """Images and poses out of step (shift by +-1..max_shift) or shuffled.

    ``search``: the search already made on these observations (used when it
    :meth:`~PairingSearch.matches` them, else searched here).
    """
    th = thresholds()
    if given_cost <= th.readings.bad_cost:
        return []
    if search is None or not search.matches(obs, fmt, invert=invert):
        search = PairingSearch(obs, fmt, invert=invert)
    best = search.best_shift()
    partial = search.best_partial()
    if (
        partial is not None
        and is_clearly_better(partial[3].cost, given_cost)
        and (
            best is None
            or not is_clearly_better(best[1].cost, given_cost)
            or _n_unexplained(partial[3]) < _n_unexplained(best[1])
        )
    ):
        return [_partial_shift_finding(obs, partial, given_cost)]
    if best is not None and is_clearly_better(best[1].cost, given_cost):
        s, fit, keep = best
        direction = f"+{s}" if s > 0 else str(s)
        kind_hint = (
            f"the first {s} pose line(s) belong to no image: delete them (or the images are numbered "
            f"from 0 and the first {s} of them were deleted)"
            if s > 0
            else f"the pose(s) of the first {-s} image(s) are missing: the first pose line holds the pose of the "
            f"image {-s} after the first"
        )
        return [
            Finding(
                "pairs_shifted",
                "fail",
                f"Images and robot poses are out of step by {abs(s)}: image k belongs to pose k{direction}",
                f"pairing image k with pose k{direction}: board scatter {fit.median_rot_deg:.3f} deg / "
                f"{fit.median_trans_mm:.2f} mm (median over {int(keep.sum())} views), a cost of {best[1].cost:.2f} "
                f"against {given_cost:.1f} as paired now ({_cost_text()})",
                f"re-pair the poses with the images ({kind_hint}); capture poses and images together, by view id",
                details={
                    "shift": s,
                    "views_compared": int(keep.sum()),
                    "board_scatter_deg": fit.median_rot_deg,
                    "board_scatter_mm": fit.median_trans_mm,
                },
            )
        ]
    # a shuffle: match by signature, then check the matched pairing with a full fit
    found = search.shuffle()
    if found is None:
        return []
    assign, T, C, fit = found
    moved = [v for v in obs.ids if assign[v] != v]
    if is_clearly_better(fit.cost, given_cost):
        pairs = ", ".join(f"image {v} <- pose {assign[v]}" for v in moved[:10])
        return [
            Finding(
                "pairs_shuffled",
                "fail",
                f"Images and robot poses are shuffled: {len(moved)} of {obs.n} images carry another view's pose",
                f"matched by the rotation angles between views: {pairs}{' ...' if len(moved) > 10 else ''}; with this "
                f"pairing the board scatters by {fit.median_rot_deg:.3f} deg / {fit.median_trans_mm:.2f} mm (median), "
                f"a cost of {fit.cost:.2f} against {given_cost:.1f} as paired now ({_cost_text()})",
                "re-pair images and poses by view id (the recording lost the order); re-capture if unsure",
                view_ids=tuple(moved),
                details={
                    "assignment": {v: assign[v] for v in moved},
                    "board_scatter_deg": fit.median_rot_deg,
                    "board_scatter_mm": fit.median_trans_mm,
                },
            )
        ]
    return []


def _n_unexplained(fit) -> int:
    """How many views a pairing's board fit leaves unexplained.

    How many views a pairing's board fit leaves unexplained (a view's implied board beyond the cost a
    right reading reaches, :attr:`thresholds().readings.good_cost`).
    """
    return int(np.sum(fit.view_costs() > thresholds().readings.good_cost))


def _search_partial(obs: PoseObservations, fmt: PoseFormat, invert: bool) -> Optional[tuple]:
    """The best pairing shifted by one line from one image on.

    The best pairing shifted by one line from one image on (a capture that saved a pose without its image, or
    an image without its pose, with the numbering carried on): for each shift s = +-1 and each image ``first``
    in file order with two or more images before and after, the images before ``first`` keep their poses, and
    from ``first`` on each takes the pose s lines from its own; for s = -1 the image just before ``first``
    has no pose (left out). Returns (s, first, lone (the image without a pose, or None), fit, keep, keys),
    the fit with the fewest unexplained views (then the lowest cost), or None. Above
    :data:`~handeye.diagnose.consistency.SPLIT_SCAN_MAX` images the search is coarse to fine
    (:func:`~handeye.diagnose.consistency.split_candidates`).
    """
    order = list(obs.raw.order)
    pos = {k: i for i, k in enumerate(order)}
    views = sorted((v for v in obs.ids if v in pos), key=pos.__getitem__)

    def ranked(shift: int, k: int):
        first = views[k]
        lone = views[k - 1] if shift < 0 else None
        keys = {
            v: order[pos[v] + shift] if pos[v] >= pos[first] else v
            for v in views
            if v != lone and 0 <= pos[v] + (shift if pos[v] >= pos[first] else 0) < len(order)
        }
        keep = np.array([v in keys for v in obs.ids])
        T = read_poses(obs.raw, fmt, [keys[v] for v in obs.ids if v in keys])
        if T is None or keep.sum() < 5:
            return None
        fit = _fit_pairing(obs, keep, T, invert)
        if fit is None:
            return None
        return (_n_unexplained(fit), fit.cost), (shift, first, lone, fit, keep, keys)

    # every image as the first one out of step, or coarse to fine above SPLIT_SCAN_MAX of them: the views
    # unexplained grow with the distance from the true first one
    lo, hi = 2, len(views) - 2
    coarse, step = split_candidates(lo, hi)
    found = []
    for shift in (1, -1):
        tried = {k: ranked(shift, k) for k in coarse}
        if step > 1:
            for kc in sorted((k for k in coarse if tried[k] is not None), key=lambda k: tried[k][0])[:2]:
                for k in range(max(lo, kc - step + 1), min(hi, kc + step - 1) + 1):
                    if k not in tried:
                        tried[k] = ranked(shift, k)
        found += [r for _, r in sorted(tried.items()) if r is not None]
    return min(found, key=lambda r: r[0])[1] if found else None


def _partial_shift_finding(obs: PoseObservations, found: tuple, given_cost: float) -> Finding:
    """The finding of a pairing shifted by one line from one image on (:func:`_search_partial`)."""
    s, first, lone, fit, keep, keys = found
    order = list(obs.raw.order)
    b = order.index(first)
    if s > 0:
        title = (
            f"Images and robot poses are out of step from image {first} on: each image from there carries the "
            f"pose written for the image after it; the pose written for image {order[b]} belongs to no image"
        )
        fix = (
            f"delete pose line {b + 1} of the pose file (the pose written for image {order[b]}: a capture saved "
            "the robot pose but no image), then calibrate again"
        )
    else:
        title = (
            f"Images and robot poses are out of step from image {first} on: each image from there carries the "
            f"pose written for the image before it; image {lone} has no pose"
        )
        fix = (
            f"the pose of image {lone} is missing from the pose file (a capture saved the image but no robot "
            f"pose): add it as pose line {order.index(lone) + 1}, or remove image {lone} and number the later "
            "images one lower; then calibrate again"
        )
    moved = [v for v in obs.ids if keys.get(v, v) != v]
    return Finding(
        "pairs_shuffled",
        "fail",
        title,
        f"pairing each image from {first} on with the pose {s:+d} line from its own: board scatter "
        f"{fit.median_rot_deg:.3f} deg / {fit.median_trans_mm:.2f} mm (median over {int(keep.sum())} views, "
        f"{_n_unexplained(fit)} unexplained), a cost of {fit.cost:.2f} against {given_cost:.1f} as paired now "
        f"({_cost_text()})",
        fix,
        view_ids=tuple(sorted(moved + ([lone] if lone else []), key=order.index)),
        details={
            "assignment": {v: keys[v] for v in moved},
            "partial_shift": s,
            "shift_from_image": first,
            "image_without_pose": lone,
            "board_scatter_deg": fit.median_rot_deg,
            "board_scatter_mm": fit.median_trans_mm,
        },
    )


def partial_shift_findings(obs: PoseObservations, fit, flagged: Sequence[str]) -> tuple[list, set]:
    """Flagged views that are the tail (or head) of a pairing out of step from one image on.

    Views flagged for their robot poses that are the tail (or the head) of a pairing out of step from one
    image on (:func:`_search_partial`): when the shifted pairing leaves fewer views unexplained than the given
    one and every flagged view is among those it re-pairs, (its finding, the views it explains); else ([], set()).
    A shift of the last few views leaves the median fit as given good, so the pairing check does not search.
    """
    if len(flagged) < 2:
        return [], set()
    found = _search_partial(obs, obs.raw.fmt, False)
    if found is None:
        return [], set()
    s, first, lone, pfit, keep, keys = found
    moved = {v for v in obs.ids if keys.get(v, v) != v} | ({lone} if lone else set())
    if _n_unexplained(pfit) >= _n_unexplained(fit) or not set(flagged) <= moved:
        return [], set()
    return [_partial_shift_finding(obs, found, fit.cost)], moved


def swapped_pose_findings(
    obs: PoseObservations, check: RobotPoseCheck, flagged: Sequence[str], fmt: PoseFormat
) -> tuple[list, set]:
    """Flagged views whose image fits exactly one other recorded pose: (findings, the views explained).

    Each flagged view's camera-implied pose is tested against every recorded pose at once (one
    vectorised call of the robot-pose test per flagged view: linear in the view count).
    """
    if not 1 <= len(flagged) <= thresholds().pairing.max_swap_candidates:
        return [], set()
    idx = {v: k for k, v in enumerate(obs.ids)}
    keys = [k for k in obs.raw.order if k in obs.raw.values]
    T_all = read_poses(obs.raw, fmt, keys)
    if T_all is None:
        return [], set()
    t = check.test
    rot, trans = t.rot_deg, t.trans_mm
    flagged_set = set(flagged)
    swapped: set = set()
    out = []
    for a in flagged:
        if a in swapped:
            continue
        ka = idx[a]
        t_all = check.test_poses(ka, T_all)
        fits = [
            (key, float(t_all.rot_deg[p]), float(t_all.trans_mm[p]))
            for p, key in enumerate(keys)
            if key != a and not t_all.flagged[p] and t_all.distance[p] < 0.5 * t.distance[ka]
        ]
        if len(fits) != 1:
            continue
        b, r_b, t_b = fits[0]
        if b in idx and b in flagged_set and b not in swapped:
            kb = idx[b]
            t_ab = check.test_poses(ka, obs.T[kb])  # view a's image with b's pose
            t_ba = check.test_poses(kb, obs.T[ka])
            if t_ba.flagged[0]:
                continue
            swapped |= {a, b}
            out.append(
                Finding(
                    "pairs_shuffled",
                    "fail",
                    f"The robot poses of views {a} and {b} are swapped",
                    f"view {a} disagrees with its own pose by {rot[ka]:.2f} deg / {trans[ka]:.1f} mm and "
                    f"view {b} by {rot[kb]:.2f} deg / {trans[kb]:.1f} mm; with each other's pose they "
                    f"agree ({t_ab.rot_deg[0]:.3f} deg / {t_ab.trans_mm[0]:.2f} mm and "
                    f"{t_ba.rot_deg[0]:.3f} deg / {t_ba.trans_mm[0]:.2f} mm)",
                    "swap the two pose entries (and pair images and poses by view id when recording)",
                    view_ids=(a, b),
                    details={"swapped": [a, b]},
                )
            )
        elif b not in idx:
            swapped.add(a)
            out.append(
                Finding(
                    "pairs_shuffled",
                    "fail",
                    f"View {a}'s image carries the robot pose recorded for view {b}",
                    f"view {a} disagrees with its own pose by {rot[ka]:.2f} deg / {trans[ka]:.1f} mm but agrees "
                    f"with the pose of view {b} ({r_b:.3f} deg / {t_b:.2f} mm), whose image was not used",
                    f"swap the pose entries of views {a} and {b} (and pair images and poses by view id when recording)",
                    view_ids=(a, b),
                    details={"swapped": [a, b]},
                )
            )
    return out, swapped
