"""Benchmark of recalibration: verify's power, false alarms and change estimate; compare's p-values;
calibrate --prior after a bump; verify's time on rendered images.

Simulated installs (corner level, :func:`handeye.sim.corners.make_corner_session`: 11x8 board,
1280x720, 0.3 px corners), both mounting modes, robot errors iid (0.2 mm / 0.05 deg per axis) or from
the kinematic model (RM65-B, :mod:`handeye.sim.robot_error`; the verification sees the same arm; the
views carry the arm's encoder readings, as a session with joint angles does). An install is a 20-view
session (``--install-views N``: N views) refined as the pipeline does (OpenCV seeds,
:func:`handeye.refine.refine`; the kinematic installs name their arm, as ``calibrate --robot rm65``;
``--validated``: with the verdict covariance ``calibrate`` writes); a verification is 6 views of the same
rig (new noise) at the poses
``verify --plan`` proposes against the install (``--poses planned``, the default: what a user is told
to capture; a kinematic arm's unreachable ones topped up with random poses) or at random poses
(``--poses random``), undisturbed or with the camera bumped by 1 mm and 0.1 deg in random directions,
checked by :func:`handeye.recal.verify.verify_views`. Printed per mode and robot model:

- power: share of bumped verifications called drifted (goal >= 95 %);
- false alarms: share of undisturbed ones called drifted at alpha 5 % (goal <= 6 %);
- change within 2 sigma: among detections, the true bump inside the estimate's 2-sigma region
  (squared Mahalanobis under the change covariance <= chi2_6 at 95.45 %, the 6-D analogue of 2 sigma;
  goal >= 90 %);
- the median 1-sigma of the change (the installed uncertainty and the 6 views', norm over the axes);
- power 2x: the same bump doubled (2 mm / 0.2 deg);
- the theory beside it (:func:`theory`): the power the non-central chi-square predicts for each trial's
  bump with the change covariance the test used, with the model's installed covariance instead of the
  verdict's, the ceiling (perfect new views), the sigma of the change split into the install's (X given
  what the new views share with it: its intrinsics, and a kinematic install's DH offsets) and the new
  views' (a perfect install), and the factor on all the installed sigmas at
  which the average power over bump directions reaches 95 % (1: this install suffices; 0: not even a
  perfect install, the new views fall short): its median, its 10th percentile (the factor that makes
  90 % of such installs suffice) and the share of installs that suffice as they are.

compare (``--compare N``): two independent 20-view calibrations of one rig, iid robot errors; the KS
test of the p-values against uniform (goal: not rejected at 1 %) and the share of 2 mm bumps flagged
(goal 100 %), for compare's test and for X alone.

--prior (``--prior N``): 5 new views after a 1 mm / 0.1 deg bump, refined with the install as the prior
(the decision of :mod:`handeye.recal.prior`: verify's test on the same views, and without the prior on
X, the intrinsics prior kept, when they contradict it; and as with ``--board-unmoved``, the board's pose
kept too unless verify finds it moved), against a fresh 20-view calibration of the bumped rig: RMS error
of X against the truth (goal: no worse), and without a bump the share of runs that report a
contradiction (nominal 5 %). ``--poses`` as for verify (5 planned views by default).

Timing (``--timing``): verify_session on a rendered 6-view session at 1280x720 (detection included,
rendering not), median of 3.

Figures (2026-12-02, 2-core machine, ``--validated``, planned poses, the final code; 300 trials per row
unless said):

::

    verify: 6 views, camera bumped 1 mm / 0.1 deg; alpha 5 %; installed covariance: cov_x_6x6_verdict
      model     mode         trials   power false al. in 2 sig  sigma mm sigma deg  time s power 2x
      kinematic eye_in_hand     300   99.3%      2.7%    96.6%      0.39     0.048    0.05   100.0%
      kinematic eye_to_hand     299   99.7%      2.3%    93.3%      0.27     0.035    0.05   100.0%
      iid       eye_in_hand     600   96.5%      5.3%    91.7%      0.43     0.057    0.03   100.0%
      iid       eye_to_hand     300   99.3%      5.3%    94.0%      0.55     0.056    0.03   100.0%

(``--trials 300 --models kinematic``; ``--trials 300 --models iid`` and for eye-in-hand also ``--first-seed
300``; one eye-to-hand kinematic trial skipped: its planned pose could not place the board in the image.)
The theory rows (non-central chi-square with each trial's change covariance) predict 99.1 / 99.9 %
(kinematic) and 97.9 / 99.6 % (iid).

The test's reference: F(dof, nu) with nu the installed robot noise level's degrees of freedom
(:func:`handeye.stats.wald_p_value`, :attr:`handeye.recal.loaded.LoadedResult.robot_noise_dof`). With the
chi-square reference (the noise level taken as known) the iid eye-in-hand row called 8.0 % of 600
undisturbed verifications drifted (2.2 % at 1 %, 0.7 % at 0.1 %: the tail of 6 F(6, nu) with nu about 30-40
where the install's Satterthwaite value is about 50); with nu the
fewest degrees of freedom of the install's robot sigmas (the translation's, about 16) 2.3 % and the power
fell to 94.7 %. The kinematic rows' 2.3-2.7 % (4.7 / 5.0 % with chi-square) say that the encoder noise's
degrees of freedom overstate its part in the change's covariance there: a conservative test.

What the power rests on: the change's sigma is the install's X given what the new views share with it
(the intrinsics, and a kinematic install's DH offsets) and the 6 new views' own, in quadrature.

- Kinematic: the install's estimated DH offsets, with their covariance with X and the intrinsics, are
  the new views' DH prior, and the test takes them apart like the intrinsics
  (:func:`handeye.recal.verify.with_installed_dh`). Before (the new views under the arm's own DH prior,
  40 trials per mode) the change's sigma was 0.93 / 1.07 mm and the power 80 / 80 %: each verification
  re-learned the arm's systematic error from 6 views. The views must carry the joint readings: with the
  install's joints from inverse kinematics of the reported poses (sometimes another arm configuration
  than the one that took the view), the shared offsets were wrong for those views and eye-in-hand had
  35 % false alarms (40 trials).
- iid: nothing but the intrinsics is shared, so the install's own precision limits the power: a 20-view
  install at this noise is 0.35 mm / 0.04 deg given its intrinsics (norms over the axes). How well the
  shared intrinsics cancel matters: with the installed joint carried to the verdict's intrinsics
  covariance as validation measures it (each intrinsic against its own model sigma, so fx - fy came out as
  uncertain as fx), the change's sigma was 0.49 / 0.60 mm and 20-view installs detected 93 % / 93 % (100
  trials; 30-view installs 99.3 / 98.7 %, 300 trials). Then with the verdict's sigmas and the model's
  correlations among the intrinsics: 95.7 / 96.7 %. Now the validation measures the intrinsics against their
  joint model covariance and keeps the model's unless the folds show it wrong
  (:func:`handeye.recal.loaded.verdict_maps`): the rows above.
  ``verify --plan`` says what an install allows (the ceiling with perfect views, and the smallest drift it
  detects with 95 % power).
- False alarms are 2.3-5.3 % at the 5 % level (300 trials: +-1.3 % of sampling scatter): the test uses the
  verdict covariance of X and of the intrinsics (the model's unless the install's folds showed it wrong).

--prior (``--prior 50 --validated``, 50 installs per mode): after a 1 mm / 0.1 deg bump the contradiction is
found in 98 % (eye-in-hand) and 100 % (eye-to-hand), and the update (the 5 new views with the prior's
intrinsics, no prior on X; over all 50 bumped installs) has an RMS error of 0.447 mm / 0.104 deg and
0.629 mm / 0.102 deg, against a fresh 20-view calibration's 0.457 mm / 0.088 deg and 0.464 mm / 0.101 deg of
the same rigs. With ``--board-unmoved`` (the board found unmoved in every run, so its earlier pose kept):
0.385 mm / 0.099 deg and 0.574 mm / 0.098 deg. Without a bump: 0.374 and 0.357 mm against the fresh 0.457
and 0.464 mm, a contradiction reported in 8 % and 4 % (nominal 5 %; 50 trials: +-3 % of sampling scatter;
12 % and 12 % with the chi-square reference, 10 % and 2 % with the earlier, wider verdict covariance). So
the update is 2 % better than a fresh 20-view calibration in eye-in-hand translation, 1 % worse in
eye-to-hand rotation and 18-36 % worse elsewhere; with the board's pose 16 % better in eye-in-hand
translation, 3 % better in eye-to-hand rotation, and 12-24 % worse elsewhere.
What limits it is the 5 views themselves: once X has moved, the prior can only give what did not move (the
intrinsics, the board if it stayed), and each new view measures X through one robot pose. In theory (the collector's
information model, intrinsics known, 150 candidate poses, 5 chosen greedily) the 5 best views with the
board known give 0.28 mm / 0.047 deg eye-in-hand and 0.39 mm / 0.044 deg eye-to-hand, against 0.32 mm /
0.036 deg and 0.34 mm / 0.036 deg for 20 views: the robot's own 0.05 deg per axis over 5 views is 0.039 deg
already. ``--board-unmoved`` is the user's statement, not a test: verify's board check catches a moved
board only beyond a few sigma of 5 views, and a board moved by less puts its move into X (in a probe of 6
installs per mode, a board moved by 1.2 mm eye-in-hand / 1.5 mm eye-to-hand on top of the bump was never
found moved, and X's RMS error was 0.71 / 1.25 mm with the board's pose against 0.46 / 0.61 mm without).

``--compare 100 --validated`` and the same with ``--first-seed 100`` (200 pairs per mode, compare's test of
X given the intrinsics difference, :mod:`handeye.recal.compare`, its p-value from F with the two results'
robot noise degrees of freedom): KS of the p-values against uniform D = 0.102, p = 0.028 (eye-in-hand) and
D = 0.051, p = 0.667 (eye-to-hand), not rejected at 1 %; 5.5 % and 6.0 % of the unchanged pairs called
drifted at 5 %; a 2 mm bump flagged in 100 % and 100 %. The intrinsics' own test: KS p = 0.96 and 0.14. The
test of X alone on the same pairs: 4.5 % and 6.0 % called drifted (KS p = 0.24 and 0.003), the bump flagged
in 97.5 % and 96.0 % (the difference of two 20-view calibrations has ~0.42 mm sigma per axis: 2 mm is a
non-centrality of ~22). With the chi-square reference (the noise levels taken as known) 6.5 % and 7.0 %
were called drifted (KS p = 0.031 and 0.671). What made the p-values uniform is the verdict
covariance's test (:mod:`handeye.refine.validation`): it is the model's unless the folds show the model
wrong, each fold measured against what the model predicts for it. Before, the verdict took the larger of
the model and the folds' jackknife spread in every session; the jackknife exceeds the model's covariance
when views inform the result unequally (1.2x in variance for X, 3-5x for the intrinsics here), so the
verdicts were wider than the truth, the p-values leaned toward 1 (KS rejected, D = 0.17 and 0.22) and 2.5 %
of the unchanged pairs were called drifted. On real data the same test between the halves of each set
stays within chi-square(6) (``benchmarks/bench_realdata.py``, compare's column: medians 1.2-6.5, at most 1
of 11 halvings above 12.6).

``--timing``: 6 rendered views at 1280x720, detection included: median 0.17 s wall at load average 1.8
(runs 0.24, 0.17, 0.15; detection 0.10 s, the verification 0.05 s).

``--unchanged N --validated`` (N 20-view installs per mode, iid robot errors; each checked with 4, 6 and 8
planned views of the rig as installed, as ``collect --verify-against`` simulates it, and of the install's
truth; alpha 5 %; "expected" and "own mean": what the test's covariance predicts when the change is the new
views' error alone, chi-square weights from ``DriftTest.change_cov_new``; 2026-12-06, seeds 100-114 and
200-229 eye-in-hand, 0-24 eye-to-hand):

::

      mode         views     truth checks false al. expected  mean T ref mean own mean f.a. chi2
      eye_in_hand      4 installed     45      2.2%     0.3%    4.57     6.34     4.11      4.4%
      eye_in_hand      4       rig     45      2.2%     5.0%    6.53     6.34      nan      4.4%
      eye_in_hand      6 installed     45      2.2%     0.1%    3.90     6.34     3.42      2.2%
      eye_in_hand      6       rig     45      8.9%     5.0%    6.38     6.34      nan      8.9%
      eye_in_hand      8 installed     45      0.0%     0.0%    3.36     6.34     3.00      0.0%
      eye_in_hand      8       rig     45      4.4%     5.0%    6.23     6.34      nan      6.7%
      eye_to_hand      4 installed     25      0.0%     0.7%    4.55     6.16     4.48      0.0%
      eye_to_hand      4       rig     25      0.0%     5.0%    6.05     6.16      nan      4.0%
      eye_to_hand      6 installed     25      0.0%     0.3%    3.42     6.16     3.90      0.0%
      eye_to_hand      6       rig     25      0.0%     5.0%    5.88     6.16      nan      4.0%
      eye_to_hand      8 installed     25      0.0%     0.1%    3.97     6.16     3.46      0.0%
      eye_to_hand      8       rig     25      8.0%     5.0%    6.71     6.16      nan      8.0%

With the install's truth the mean statistic is at its reference's (6 F(6, nu): 6.2-6.3; sd of a mean of 45
checks about 0.55); 30 more eye-in-hand installs (seeds 0-29) gave 6.0 / 6.7 / 7.0 and 3.3 / 6.7 / 3.3 %, all
75 together 6.3 / 6.5 / 6.5 and 2.7 / 8.0 / 4.0 %. With the rig as installed the install's error is absent
from the change and the test is conservative: the statistic is the new views' part, about 1.1x what their
covariance predicts (the ratio nu / (nu - 2) of a robot sigma estimated with nu ~ 16-50 degrees of freedom).
The same chain on rendered images (``collect`` 8 views, ``calibrate``, ``collect --verify-against`` 4
views, the rig as installed): mean statistic 5.2 and 1 false alarm in 26 eye-in-hand checks, 5.7 and none
in 14 eye-to-hand (two more eye-to-hand installs had a distortion the simulator could not invert).
These rows were measured before the plan's ties were broken by order (its first view had been chosen on
rounding noise); after (``--unchanged 20 --first-seed 300``) the twelve rows are alike (mean statistic with
the install's truth 5.8-7.4 eye-in-hand and 6.1-8.1 eye-to-hand over 20 checks, sd of such a mean about
0.8), and ``--trials 20 --models iid --first-seed 300`` detects 100 % / 100 % of the 1 mm / 0.1 deg bumps
with the change's sigma 0.43 / 0.55 mm as in the table above (theory 99.1 / 99.7 %).

Usage: python benchmarks/bench_recal.py --trials 300 --validated --compare 100 --prior 50 --timing --jobs 2
(per mode and robot model; the issue's counts; --jsonl keeps every trial so that a long run can be
reported with --from-jsonl, and --first-seed continues one; quick look: --trials 5 --compare 5 --prior 2).
Progress on stderr, figures on stdout.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_refine import closed_forms, refine_views  # noqa: E402  (one copy of the pipeline's seeding)

MODES = ("eye_in_hand", "eye_to_hand")
MODELS = ("iid", "kinematic")
NOISE_PX = 0.3
IID = (0.2, 0.05)  # mm, deg per axis
BUMP_MM, BUMP_DEG = 1.0, 0.1
CHI2_2SIGMA_6 = stats.chi2.ppf(stats.chi2.cdf(4.0, 1), 6)  # the 6-D region with the mass of +-2 sigma


def session(*, mode, model, seed, n_views, rig=None, model_seed=None):
    from handeye.sim.corners import make_corner_session

    kw = dict(robot_error="iid", robot_noise=IID) if model == "iid" else dict(robot_error=model)
    return make_corner_session(
        mode=mode, n_views=n_views, seed=seed, noise_px=NOISE_PX, rig=rig, robot_model_seed=model_seed, **kw
    )


def calibrate(s, options=None):
    from handeye.refine import RefineOptions, refine

    intr, closed = closed_forms(s)
    est = closed["tsai"]
    return refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=refine_views(s),
        intrinsics=intr,
        T_x0=est.T_x,
        T_board0=est.T_board,
        options=options or RefineOptions(),
        starts=closed,
    )


KINEMATIC_ARM = "rm65"  # the simulator's arm (handeye.sim.robot_error.DEFAULT_ARM)


def install(mode, model, seed, validated=False, n_views=20):
    from handeye.recal.loaded import load_result, result_from_refinement
    from handeye.refine import RefineOptions

    s = session(mode=mode, model=model, seed=seed, n_views=n_views)
    # the kinematic installs name their arm, as calibrate --robot does (the refinement models its DH errors)
    r = calibrate(s, RefineOptions(arm=KINEMATIC_ARM) if model == "kinematic" else None)
    val = None
    if validated and r.status == "ok":
        from handeye.refine.validation import validate

        val = validate(r, object_points=s.target.object_points(), views=refine_views(s), halves=False)
    return s, r, load_result(result_from_refinement(r, target=s.target, validation=val))


def random_bump(rng, mm=BUMP_MM, deg=BUMP_DEG) -> np.ndarray:
    w, u = rng.normal(size=3), rng.normal(size=3)
    return np.r_[np.radians(deg) * w / np.linalg.norm(w), 1e-3 * mm * u / np.linalg.norm(u)]


def views_at(poses, *, mode, model, rig, seed, model_seed, target, intrinsics):
    """RefineViews of a rig ``(T_x, T_board)`` seen from the robot poses ``poses`` (N,4,4; the flange goes
    there): corners with NOISE_PX, those outside the image or behind the camera dropped; robot readings with
    the iid errors or read through the kinematic model's arm (the one of ``model_seed``, as the install's);
    poses the true arm cannot reach are skipped."""
    from handeye.camera import pixels_from_board_points
    from handeye.mounting import mounting
    from handeye.refine import RefineView
    from handeye.sim.scenarios import perturb_T_base_end, random_streams

    rng = np.random.default_rng(seed)
    T_true = np.asarray(poses, float).reshape(-1, 4, 4)
    q_enc = None
    if model == "kinematic":
        from handeye.sim.robot_error import make_kinematic_error, reachable, report_poses

        kin = make_kinematic_error(rng=random_streams(model_seed)["robot_model"])
        q = [reachable(kin, T) for T in T_true]
        T_true = np.array([T for T, qk in zip(T_true, q, strict=False) if qk is not None]).reshape(-1, 4, 4)
        q_enc, T_rep = report_poses(kin, np.array([qk for qk in q if qk is not None]), rng=rng)
    else:
        T_rep = perturb_T_base_end(T_true, rng=rng, sigma_mm=IID[0], sigma_deg=IID[1])
    C = mounting(mode).predict_T_cam_board(rig[0], rig[1], T_true)
    obj = target.object_points()
    views = []
    for k in range(len(T_true)):
        z = obj @ C[k, :3, :3].T[:, 2] + C[k, 2, 3]
        uv = pixels_from_board_points(C[k], obj, intrinsics) + rng.normal(0.0, NOISE_PX, size=(len(obj), 2))
        ok = (z > 0) & np.all((uv >= 0) & (uv < [intrinsics.width, intrinsics.height]), axis=1)
        if ok.sum() >= 12:
            views.append(
                RefineView(str(k + 1), np.flatnonzero(ok), uv[ok], T_rep[k], None if q_enc is None else q_enc[k])
            )
    return views


def planned_poses(inst, n_views: int, model: str) -> np.ndarray:
    """The poses ``handeye verify --plan`` proposes against ``inst``, ``n_views`` of them (the plan's goal set
    unreachable so that it does not stop early); kinematic: twice as many, the unreachable ones are skipped."""
    from handeye.recal.plan import plan_verification

    p = plan_verification(inst, max_views=n_views if model == "iid" else 2 * n_views, power=1.0 - 1e-12)
    return np.array(p.poses)


CHI2_CRIT_6 = stats.chi2.isf(0.05, 6)


def power_of(S: np.ndarray, drifts: np.ndarray) -> np.ndarray:
    """Power of verify's test at 5 % for each drift (K,6) when the change has covariance ``S`` (6,6):
    ``P(ncx2(6, delta^T S^-1 delta) > chi2_6(0.95))``."""
    nc = np.einsum("ki,ij,kj->k", drifts, np.linalg.inv(S), drifts)
    return stats.ncx2.sf(CHI2_CRIT_6, 6, np.maximum(nc, 1e-12))


def scaled_install(inst, c: float):
    """The installed result with all its covariances (X, the intrinsics, their joint) times ``c**2``: an install
    with ``1/c**2`` times the views of the same kind."""
    from dataclasses import replace

    j, dh = inst.cov_x_intrinsics, inst.dh_joint
    return replace(
        inst,
        cov_x=c**2 * inst.cov_x,
        cov_x_intrinsics=None if j is None else (j[0], c**2 * j[1], c**2 * j[2]),
        dh_joint=None if dh is None else (dh[0], c**2 * dh[1], c**2 * dh[2], c**2 * dh[3]),
    )


def theory(inst, r_model, v, bump, *, n_dirs: int = 400) -> dict:
    """verify's theoretical power (non-central chi-square) for the verification ``v`` of the undisturbed rig
    against ``inst``: for this trial's bump and on average over random bump directions; with the model's
    installed covariance instead of the verdict's; the ceiling (perfect new views: the installed X given what
    they share with it, its intrinsics and DH offsets, is all that is left); the sigmas of the change with a
    perfect install (the new views alone) and
    with perfect new views; ``scale95``: the factor on all the installed sigmas at which the average power
    reaches 95 % with these new views (0: not even a perfect install does)."""
    from dataclasses import replace

    from handeye.recal.verify import test_refined

    prior = v.refined.options.prior  # the one verify_views refined the new views under
    dirs = np.array([random_bump(np.random.default_rng(k)) for k in range(n_dirs)])

    def V(c, i=inst):
        return test_refined(scaled_install(i, c), v.refined, prior, min_variance_share=1e-3).change_cov

    avg = lambda S: float(np.mean(power_of(S, dirs)))  # noqa: E731
    j, dh = inst.cov_x_intrinsics, inst.dh_joint
    S_perfect_new = inst.cov_x
    if j is not None:  # X given what the new views share with the install: the intrinsics (and the DH offsets)
        C, K = j[1], j[2]
        if dh is not None and prior.dh_offsets is not None:
            C, K = np.hstack([C, dh[1]]), np.block([[K, dh[2]], [dh[2].T, dh[3]]])
        S_perfect_new = inst.cov_x - C @ np.linalg.solve(K, C.T)
    V1, V0 = V(1.0), V(1e-3)
    if avg(V0) < 0.95:
        scale = 0.0
    elif avg(V1) >= 0.95:
        scale = 1.0
    else:
        lo, hi = 1e-3, 1.0
        for _ in range(20):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if avg(V(mid)) >= 0.95 else (lo, mid)
        scale = lo
    from handeye.recal.loaded import _joints

    # the model's covariances throughout (X, the intrinsics, the DH offsets), as the refinement gave them
    model = replace(
        inst, cov_x=r_model.cov_x_6x6, **_joints({"cov_x_intrinsics": r_model.cov_x_intrinsics}, r_model.cov_x_6x6)
    )
    return dict(
        power=float(power_of(V1, bump[None])[0]),
        power_avg=avg(V1),
        power_model_avg=avg(V(1.0, model)),
        ceiling_avg=avg(S_perfect_new),
        scale95=scale,
        s0_mm=float(1e3 * np.sqrt(np.trace(S_perfect_new[3:, 3:]))),
        s0_deg=float(np.degrees(np.sqrt(np.trace(S_perfect_new[:3, :3])))),
        snew_mm=float(1e3 * np.sqrt(np.trace(V0[3:, 3:]))),
        snew_deg=float(np.degrees(np.sqrt(np.trace(V0[:3, :3])))),
        v_mm=float(1e3 * np.sqrt(np.trace(V1[3:, 3:]))),
        v_deg=float(np.degrees(np.sqrt(np.trace(V1[:3, :3])))),
    )


def verify_trial(args) -> dict:
    from dataclasses import replace

    from handeye.errors import HandeyeError
    from handeye.frames import se3_exp
    from handeye.recal.verify import verify_views

    mode, model, seed, validated, poses, install_views = args
    try:
        s, r, inst = install(mode, model, seed, validated, install_views)
        if r.status != "ok":
            return dict(mode=mode, model=model, seed=seed, skipped=f"install: {r.failure_reason}")
        bump = random_bump(np.random.default_rng(seed + 7919))
        out = dict(mode=mode, model=model, seed=seed, cov=inst.cov_source, poses=poses, install_views=install_views)
        planned = planned_poses(inst, 6, model) if poses == "planned" else None
        for name, xi in (("still", np.zeros(6)), ("bumped", bump), ("bumped2", 2.0 * bump)):
            rig = (s.T_x_true @ se3_exp(xi), s.T_board_true)
            if planned is None:
                views = refine_views(
                    session(mode=mode, model=model, seed=seed + 100000, n_views=6, rig=rig, model_seed=seed)
                )
            else:  # the arm may not reach every planned pose: topped up with random poses
                views = views_at(
                    planned,
                    mode=mode,
                    model=model,
                    rig=rig,
                    seed=seed + 100000,
                    model_seed=seed,
                    target=s.target,
                    intrinsics=s.intrinsics,
                )[:6]
                if len(views) < 6:
                    extra = refine_views(
                        session(
                            mode=mode, model=model, seed=seed + 100000, n_views=6 - len(views), rig=rig, model_seed=seed
                        )
                    )
                    views += [replace(x, view_id=f"r{x.view_id}") for x in extra]
                    out["topped_up"] = len(extra)
            t0 = time.perf_counter()
            v = verify_views(inst, views=views, object_points=s.target.object_points())
            e = v.test.change_xi - xi
            out[name] = dict(
                drifted=v.drifted,
                p=v.test.p_value,
                dof=v.test.dof,
                secs=time.perf_counter() - t0,
                within=float(e @ np.linalg.solve(v.test.change_cov, e)) <= CHI2_2SIGMA_6,
                sig_mm=float(np.linalg.norm(v.change["sigma_trans_mm"])),
                sig_deg=float(np.linalg.norm(v.change["sigma_rot_deg"])),
            )
            if name == "still":
                out["theory"] = theory(inst, r, v, bump)
        return out
    except HandeyeError as e:
        return dict(mode=mode, model=model, seed=seed, skipped=str(e)[:100])
    except Exception as e:  # noqa: BLE001 - a crash is counted with its traceback, not allowed to stop the run
        import traceback

        return dict(
            mode=mode,
            model=model,
            seed=seed,
            skipped=f"crashed: {type(e).__name__}: {e}"[:100],
            traceback=traceback.format_exc(),
        )


UNCHANGED_VIEWS = (4, 6, 8)


def unchanged_trial(args) -> dict:
    """Short checks (4, 6 and 8 views at the planned poses) of an unchanged rig against one install.

    Two readings of "unchanged": the rig is the installed result itself (X, board and intrinsics as installed,
    as ``collect --verify-against`` simulates it) or the rig the install was calibrated on (its truth, the
    install's error included). Per check: the statistic, its dof, the p-value and, for the installed rig, the
    false-alarm probability and the mean the test's own covariance predicts when the change is the new views'
    error alone (``sum_i w_i z_i^2``, w the eigenvalues of ``V^-1 V_new``, ``V_new`` the new views' part of the
    change's covariance, :attr:`handeye.recal.drift.DriftTest.change_cov_new`).
    """
    from handeye.errors import HandeyeError
    from handeye.recal.verify import verify_views
    from handeye.stats import wald_p_value, weighted_chi2_sf

    mode, seed, validated, install_views = args
    try:
        s, r, inst = install(mode, "iid", seed, validated, install_views)
        if r.status != "ok":
            return dict(mode=mode, seed=seed, skipped=f"install: {r.failure_reason}")
        out = dict(mode=mode, seed=seed, nu=inst.robot_noise_dof, checks=[])
        truths = {
            "installed": ((inst.T_x, inst.T_board), inst.intrinsics),
            "rig": ((s.T_x_true, s.T_board_true), s.intrinsics),
        }
        for n in UNCHANGED_VIEWS:
            planned = planned_poses(inst, n, "iid")
            for truth, (rig, intr) in truths.items():
                views = views_at(
                    planned,
                    mode=mode,
                    model="iid",
                    rig=rig,
                    seed=seed + 1000 * n,
                    model_seed=seed,
                    target=s.target,
                    intrinsics=intr,
                )[:n]
                if len(views) < n:
                    continue
                t = verify_views(inst, views=views, object_points=s.target.object_points()).test
                crit = _critical(t.dof, t.noise_dof)
                # the statistic's weights when the change is the new views' error alone: V^-1 V_new's eigenvalues
                w = np.clip(np.linalg.eigvals(np.linalg.solve(t.change_cov, t.change_cov_new)).real, 0.0, None)
                out["checks"].append(
                    dict(
                        n=n,
                        truth=truth,
                        T=t.statistic,
                        dof=t.dof,
                        p=t.p_value,
                        ref_mean=_reference_mean(t.dof, t.noise_dof),
                        own_mean=float(w.sum()),
                        own_rate=weighted_chi2_sf(crit, w)[0] if w.sum() > 0 else 0.0,
                        p_chi2=wald_p_value(t.statistic, t.dof),
                    )
                )
        return out
    except HandeyeError as e:
        return dict(mode=mode, seed=seed, skipped=str(e)[:100])


def _critical(dof: int, nu, alpha: float = 0.05) -> float:
    """The statistic at which verify's p-value is ``alpha`` (chi-square, or dof F(dof, nu))."""
    from scipy.special import fdtri

    return float(stats.chi2.isf(alpha, dof)) if nu is None else float(dof * fdtri(dof, nu, 1.0 - alpha))


def _reference_mean(dof: int, nu) -> float:
    """The mean of verify's reference distribution: dof (chi-square) or dof nu / (nu - 2) (dof F(dof, nu))."""
    return float(dof) if nu is None or nu <= 2 else float(dof * nu / (nu - 2.0))


def report_unchanged(rows) -> None:
    """False alarms and the mean statistic per mode, number of views and reading of "unchanged"."""
    print(
        "verify on an unchanged rig: planned poses, alpha 5 %; the rig is the installed result or the install's truth"
    )
    print(
        f"  {'mode':<12}{'views':>6}{'truth':>10}{'checks':>7}{'false al.':>10}{'expected':>9}"
        f"{'mean T':>8}{'ref mean':>9}{'own mean':>9}{'f.a. chi2':>10}"
    )
    ok = [r for r in rows if "skipped" not in r]
    for mode in MODES:
        for n in UNCHANGED_VIEWS:
            for truth in ("installed", "rig"):
                cs = [c for r in ok if r["mode"] == mode for c in r["checks"] if c["n"] == n and c["truth"] == truth]
                if not cs:
                    continue
                expected = np.mean([c["own_rate"] for c in cs]) if truth == "installed" else 0.05
                print(
                    f"  {mode:<12}{n:>6}{truth:>10}{len(cs):>7}{100 * np.mean([c['p'] < 0.05 for c in cs]):>9.1f}%"
                    f"{100 * expected:>8.1f}%{np.mean([c['T'] for c in cs]):>8.2f}"
                    f"{np.mean([c['ref_mean'] for c in cs]):>9.2f}"
                    f"{np.mean([c['own_mean'] for c in cs]) if truth == 'installed' else float('nan'):>9.2f}"
                    f"{100 * np.mean([c['p_chi2'] < 0.05 for c in cs]):>9.1f}%"
                )
    skipped = [r for r in rows if "skipped" in r]
    if skipped:
        print(f"  ({len(skipped)} installs skipped: {skipped[0]['skipped'][:60]})")


def compare_trial(args) -> dict:
    from handeye.frames import se3_exp
    from handeye.recal.compare import compare_loaded
    from handeye.recal.loaded import load_result, result_from_refinement

    mode, seed, validated = args
    s, r, a = install(mode, "iid", seed, validated)

    def result_of(sx):
        rx = calibrate(sx)
        val = None
        if validated and rx.status == "ok":
            from handeye.refine.validation import validate

            val = validate(rx, object_points=sx.target.object_points(), views=refine_views(sx), halves=False)
        return load_result(result_from_refinement(rx, target=sx.target, validation=val))

    b = result_of(session(mode=mode, model="iid", seed=seed + 200000, n_views=20, rig=(s.T_x_true, s.T_board_true)))
    u = np.random.default_rng(seed).normal(size=3)
    bump = np.r_[0, 0, 0, 2e-3 * u / np.linalg.norm(u)]
    c = result_of(
        session(
            mode=mode, model="iid", seed=seed + 300000, n_views=20, rig=(s.T_x_true @ se3_exp(bump), s.T_board_true)
        )
    )
    same, moved = compare_loaded(a, b), compare_loaded(a, c)
    return dict(
        mode=mode,
        seed=seed,
        p=same.p_value,
        bumped=moved.drifted,
        test=same.test,
        p_alone=same.p_value_x_alone,
        bumped_alone=bool(moved.p_value_x_alone < moved.alpha),
        p_intr=same.intrinsics.get("p_value", np.nan),
        validated=validated,
    )


def refine_from_install(inst, views, object_points, options):
    """The refinement of ``views`` as ``calibrate --prior`` runs it: from the installed intrinsics and X, the
    board where the installed X puts it (the mean over the views)."""
    from handeye.frames import mean_T
    from handeye.initial import solve_pnp
    from handeye.recal.verify import board_from_views
    from handeye.refine import refine

    C = np.stack([solve_pnp(object_points[v.corner_ids], v.image_points, inst.intrinsics)[0] for v in views])
    E = np.stack([v.T_base_end for v in views])
    B0 = mean_T(board_from_views(inst.mode, inst.T_x, E, C))
    return refine(
        mode=inst.mode,
        object_points=object_points,
        views=views,
        intrinsics=inst.intrinsics,
        T_x0=inst.T_x,
        T_board0=B0,
        options=options,
    )


def prior_trial(args) -> dict:
    from handeye.frames import pose_error, se3_exp
    from handeye.recal.loaded import VAGUE_COV_X, installed_prior
    from handeye.recal.verify import verify_views
    from handeye.refine import RefineOptions

    mode, seed, poses, validated = args
    s, r, inst = install(mode, "iid", seed, validated)
    out = dict(mode=mode, seed=seed, poses=poses)
    obj = s.target.object_points()
    planned = planned_poses(inst, 5, "iid") if poses == "planned" else None
    prior, fixed = installed_prior(inst, session_intrinsics=False)
    for name, xi in (("still", np.zeros(6)), ("bumped", random_bump(np.random.default_rng(seed + 31)))):
        rig = (s.T_x_true @ se3_exp(xi), s.T_board_true)
        if planned is None:
            views = refine_views(session(mode=mode, model="iid", seed=seed + 400000, n_views=5, rig=rig))
        else:
            views = views_at(
                planned,
                mode=mode,
                model="iid",
                rig=rig,
                seed=seed + 400000,
                model_seed=seed,
                target=s.target,
                intrinsics=s.intrinsics,
            )
        rp = refine_from_install(inst, views, obj, RefineOptions(prior=prior, fix=fixed))
        # as calibrate --prior: verify's test on the views decides; when they contradict the prior, the views
        # without the prior on X (the intrinsics prior kept)
        v = verify_views(inst, views=views, object_points=obj)
        contradicted = rp.status != "ok" or v.drifted
        # as calibrate --prior builds it: no prior on X, the intrinsics' kept; with --board-unmoved the board's too,
        # unless verify finds it moved
        board_kept = bool(v.board.get("known") and not v.board.get("moved"))
        bare, _ = installed_prior(inst, session_intrinsics=False, cov_x=VAGUE_COV_X)
        alone = refine_from_install(inst, views, obj, RefineOptions(prior=bare, fix=fixed))
        with_board = alone
        if board_kept:
            pb, _ = installed_prior(inst, session_intrinsics=False, cov_x=VAGUE_COV_X, board=True)
            with_board = refine_from_install(inst, views, obj, RefineOptions(prior=pb, fix=fixed))
        kept, kept_b = (alone, with_board) if contradicted else (rp, rp)
        fresh = calibrate(session(mode=mode, model="iid", seed=seed + 500000, n_views=20, rig=rig))
        out[name] = dict(
            contradicted=contradicted,
            board_kept=board_kept,
            err_mm=pose_error(kept.T_x, rig[0])[1],
            board_mm=pose_error(kept_b.T_x, rig[0])[1],
            board_deg=pose_error(kept_b.T_x, rig[0])[0],
            err_deg=pose_error(kept.T_x, rig[0])[0],
            fresh_mm=pose_error(fresh.T_x, rig[0])[1],
            fresh_deg=pose_error(fresh.T_x, rig[0])[0],
            alone_mm=pose_error(alone.T_x, rig[0])[1],
            alone_deg=pose_error(alone.T_x, rig[0])[0],
            installed_mm=pose_error(inst.T_x, rig[0])[1],
        )
    return out


def rms(v) -> float:
    v = np.asarray(list(v), float)
    return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")


def run_pool(fn, tasks, jobs, jsonl=None):
    """Results of ``fn`` over ``tasks``; with ``jsonl`` each is also appended to that file as it comes
    (a long run can be reported from the file with --from-jsonl)."""
    import json

    out = []
    t0 = time.perf_counter()
    sink = open(jsonl, "a", encoding="utf-8") if jsonl else None

    def keep(r):
        out.append(r)
        if sink is not None:
            sink.write(json.dumps(r, default=float) + "\n")
            sink.flush()

    from fanout import ordered_map

    for k, r in enumerate(ordered_map(fn, tasks, workers=jobs)):
        keep(r)
        if (k + 1) % 20 == 0:
            print(f"  {k + 1}/{len(tasks)} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    if sink is not None:
        sink.close()
    return out


def report_verify(rows) -> None:
    n = sorted({r.get("install_views", 20) for r in rows})
    print(
        f"verify: 6 views against a {'/'.join(map(str, n))}-view install, "
        f"camera bumped {BUMP_MM:g} mm / {BUMP_DEG:g} deg; alpha 5 %; "
        f"installed covariance: {rows[0]['cov'] if rows and 'cov' in rows[0] else 'cov_x_6x6'}"
    )
    print(
        f"  {'model':<10}{'mode':<12}{'trials':>7}{'power':>8}{'false al.':>10}{'in 2 sig':>9}"
        f"{'sigma mm':>10}{'sigma deg':>10}{'time s':>8}{'power 2x':>9}"
    )
    for model in MODELS:
        for mode in MODES:
            rs = [r for r in rows if r["mode"] == mode and r["model"] == model]
            ok = [r for r in rs if "skipped" not in r]
            if not rs:
                continue
            det = [r["bumped"] for r in ok if r["bumped"]["drifted"]]
            print(
                f"  {model:<10}{mode:<12}{len(ok):>7}{100 * np.mean([r['bumped']['drifted'] for r in ok]):>7.1f}%"
                f"{100 * np.mean([r['still']['drifted'] for r in ok]):>9.1f}%"
                f"{100 * np.mean([d['within'] for d in det]) if det else float('nan'):>8.1f}%"
                f"{np.median([r['still']['sig_mm'] for r in ok]):>10.2f}"
                f"{np.median([r['still']['sig_deg'] for r in ok]):>10.3f}"
                f"{np.median([r['still']['secs'] for r in ok]):>8.2f}"
                f"{100 * np.mean([r['bumped2']['drifted'] for r in ok]):>8.1f}%"
                + (
                    f"  ({len(rs) - len(ok)} skipped: {[r for r in rs if 'skipped' in r][0]['skipped'][:60]})"
                    if len(ok) < len(rs)
                    else ""
                )
            )


def report_theory(rows) -> None:
    """The power the test should have (non-central chi-square) beside what the trials measured."""
    print(
        "verify theory (non-central chi-square, 6 dof, 5 %; sigmas: norms over the 3 axes; install: its X given "
        "what the new views share, its intrinsics and a kinematic install's DH offsets; new views: with a perfect "
        "install):"
    )
    print(
        f"  {'model':<10}{'mode':<12}{'change sigma':>17}{'install':>17}{'new views':>17}{'pred.':>7}"
        f"{'measured':>9}{'model cov':>10}{'ceiling':>8}{'install x for 95%':>18}{'(10 %)':>7}{'ok as is':>9}"
    )
    for model in MODELS:
        for mode in MODES:
            ok = [r for r in rows if r["mode"] == mode and r["model"] == model and "theory" in r]
            if not ok:
                continue
            th = [r["theory"] for r in ok]
            med = lambda k, th=th: float(np.median([t[k] for t in th]))  # noqa: E731
            print(
                f"  {model:<10}{mode:<12}{med('v_mm'):>7.2f} mm {med('v_deg'):.3f}°{med('s0_mm'):>7.2f} mm "
                f"{med('s0_deg'):.3f}°{med('snew_mm'):>7.2f} mm {med('snew_deg'):.3f}°"
                f"{100 * np.mean([t['power'] for t in th]):>6.1f}%"
                f"{100 * np.mean([r['bumped']['drifted'] for r in ok]):>8.1f}%"
                f"{100 * np.mean([t['power_model_avg'] for t in th]):>9.1f}%"
                f"{100 * np.mean([t['ceiling_avg'] for t in th]):>7.1f}%{med('scale95'):>18.2f}"
                f"{np.percentile([t['scale95'] for t in th], 10):>7.2f}"
                f"{100 * np.mean([t['scale95'] >= 0.999 for t in th]):>8.0f}%"
            )


def report_compare(rows) -> None:
    for mode in MODES:
        rs = [r for r in rows if r["mode"] == mode]
        if not rs:
            continue
        p = np.array([r["p"] for r in rs])
        ks = stats.kstest(p, "uniform")
        pi = np.array([r["p_intr"] for r in rs])
        ksi = stats.kstest(pi[np.isfinite(pi)], "uniform")
        print(
            f"compare {mode}: {len(rs)} pairs of 20-view calibrations of one rig: KS of the p-values against "
            f"uniform D = {ks.statistic:.3f}, p = {ks.pvalue:.3f} "
            f"({'not rejected' if ks.pvalue > 0.01 else 'REJECTED'}"
            f" at 1 %); drifted at 5 %: {100 * np.mean(p < 0.05):.1f} %; 2 mm bump flagged in "
            f"{100 * np.mean([r['bumped'] for r in rs]):.1f} %; intrinsics KS p = {ksi.pvalue:.3f}; test: "
            f"{', '.join(sorted({r.get('test', 'X alone') for r in rs}))}"
        )
        alone = [r for r in rs if "p_alone" in r]
        if alone and any(r.get("test", "X alone") != "X alone" for r in alone):
            pa = np.array([r["p_alone"] for r in alone])
            print(
                f"  X alone on the same pairs: KS p = {stats.kstest(pa, 'uniform').pvalue:.3f}; drifted at 5 %: "
                f"{100 * np.mean(pa < 0.05):.1f} %; 2 mm bump flagged in "
                f"{100 * np.mean([r['bumped_alone'] for r in alone]):.1f} %"
            )


def report_prior(rows) -> None:
    for mode in MODES:
        rs = [r for r in rows if r["mode"] == mode]
        if not rs:
            continue
        b, s = [r["bumped"] for r in rs], [r["still"] for r in rs]
        c = [x for x in b if x["contradicted"]]
        print(
            f"--prior {mode}: {len(rs)} installs; 5 new views after a {BUMP_MM:g} mm / {BUMP_DEG:g} deg bump, "
            f"contradiction reported in {100 * np.mean([x['contradicted'] for x in b]):.0f} %: RMS error "
            f"{rms(x['err_mm'] for x in b):.3f} mm {rms(x['err_deg'] for x in b):.4f} deg; with --board-unmoved "
            f"(the board found unmoved in {100 * np.mean([x.get('board_kept', False) for x in b]):.0f} %) "
            f"{rms(x.get('board_mm', np.nan) for x in b):.3f} mm {rms(x.get('board_deg', np.nan) for x in b):.4f} "
            f"deg; vs fresh 20 views {rms(x['fresh_mm'] for x in b):.3f} mm {rms(x['fresh_deg'] for x in b):.4f} "
            f"deg (the install: {rms(x['installed_mm'] for x in b):.3f} mm)"
        )
        print(
            f"  the {len(c)} runs that found the contradiction: {rms(x['err_mm'] for x in c):.3f} mm "
            f"{rms(x['err_deg'] for x in c):.4f} deg; "
            f"with --board-unmoved {rms(x.get('board_mm', np.nan) for x in c):.3f}"
            f" mm {rms(x.get('board_deg', np.nan) for x in c):.4f} deg; fresh {rms(x['fresh_mm'] for x in c):.3f} mm "
            f"{rms(x['fresh_deg'] for x in c):.4f} deg"
        )
        print(
            f"  no bump: {rms(x['err_mm'] for x in s):.3f} mm {rms(x['err_deg'] for x in s):.4f} deg vs fresh "
            f"{rms(x['fresh_mm'] for x in s):.3f} mm, contradiction reported in "
            f"{100 * np.mean([x['contradicted'] for x in s]):.1f} % (nominal 5 %)"
        )


def timing() -> None:
    import tempfile

    from handeye.recal.loaded import result_from_refinement
    from handeye.recal.verify import verify_session
    from handeye.sim.vendor import write_vendor_session

    s, r, inst = install("eye_in_hand", "iid", 1)
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_vendor_session(
            Path(tmp) / "verify", n_views=6, seed=11, robot_noise=IID, image_noise=2.0, rig=(s.T_x_true, s.T_board_true)
        )
        raw = result_from_refinement(r, target=s.target)
        secs = []
        for _ in range(3):
            t0 = time.perf_counter()
            sv = verify_session(folder, raw)
            secs.append(time.perf_counter() - t0)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"verify timing: 6 rendered views at 1280x720, detection included: median {np.median(secs):.2f} s wall, "
        f"at load average {load:.1f} on {os.cpu_count()} cores (runs {', '.join(f'{x:.2f}' for x in secs)}; "
        f"stages {', '.join(f'{k} {v:.2f}' for k, v in sv.seconds.items())})"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=10, help="verify trials per mode and robot model")
    ap.add_argument("--compare", type=int, default=0, help="compare pairs per mode")
    ap.add_argument("--prior", type=int, default=0, help="--prior trials per mode")
    ap.add_argument(
        "--unchanged", type=int, default=0, help="installs per mode, each checked unchanged with 4, 6 and 8 views"
    )
    ap.add_argument("--timing", action="store_true")
    ap.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--install-views", type=int, default=20, help="views of each simulated install (verify trials)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument(
        "--validated",
        action="store_true",
        help="verify and --prior trials: installs with the validation stage's verdict covariance (as "
        "calibrate writes it)",
    )
    ap.add_argument(
        "--poses",
        choices=("planned", "random"),
        default="planned",
        help="verify and --prior trials: the new views at the poses verify --plan proposes (default) or "
        "at random poses",
    )
    ap.add_argument("--jsonl", help="append every trial's outcome to this file as it comes")
    ap.add_argument("--from-jsonl", nargs="+", help="only report the trials in these files (verify, compare, prior)")
    a = ap.parse_args()
    if a.from_jsonl:
        import json

        rows = [json.loads(line) for f in a.from_jsonl for line in open(f, encoding="utf-8") if line.strip()]
        for sel, report in (
            ([r for r in rows if "model" in r and "checks" not in r], report_verify),
            ([r for r in rows if "theory" in r], report_theory),
            ([r for r in rows if "p" in r and "model" not in r], report_compare),
        ):
            if sel:
                report(sel)
        sel = [r for r in rows if "checks" in r]
        if sel:
            report_unchanged(sel)
        sel = [r for r in rows if isinstance(r.get("still"), dict) and "err_mm" in r["still"]]
        if sel:
            report_prior(sel)
        return
    seeds = range(a.first_seed, a.first_seed + a.trials)
    if a.trials:
        tasks = [
            (mode, model, s, a.validated, a.poses, a.install_views)
            for model in a.models
            for mode in a.modes
            for s in seeds
        ]
        print(f"verify: {len(tasks)} trials", file=sys.stderr)
        rows = run_pool(verify_trial, tasks, a.jobs, a.jsonl)
        report_verify(rows)
        report_theory(rows)
    if a.compare:
        tasks = [(mode, a.first_seed + s, a.validated) for mode in a.modes for s in range(a.compare)]
        print(f"compare: {len(tasks)} pairs", file=sys.stderr)
        report_compare(run_pool(compare_trial, tasks, a.jobs, a.jsonl))
    if a.prior:
        tasks = [(mode, a.first_seed + s, a.poses, a.validated) for mode in a.modes for s in range(a.prior)]
        print(f"prior: {len(tasks)} trials", file=sys.stderr)
        report_prior(run_pool(prior_trial, tasks, a.jobs, a.jsonl))
    if a.unchanged:
        tasks = [(mode, a.first_seed + s, a.validated, a.install_views) for mode in a.modes for s in range(a.unchanged)]
        print(f"unchanged: {len(tasks)} installs", file=sys.stderr)
        report_unchanged(run_pool(unchanged_trial, tasks, a.jobs, a.jsonl))
    if a.timing:
        timing()


if __name__ == "__main__":
    main()
