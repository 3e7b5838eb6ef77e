"""Pose-only sessions by fault class: coverage of the verdict covariance, error, and the findings named.

Each session: 20 views of a simulated arm (a preset drawn per session) seen by a tracker
(:func:`handeye.sim.arm_tracker.make_arm_tracker_session`), written as a session.yaml without
``tracker_sigma`` and run through :func:`handeye.workflow.calibrate_session` (report=False); result.json
is read. Printed per class and mode: coverage of the truth inside the 95 % ellipsoid (squared
Mahalanobis of Log(X_est^-1 X_true) against the chi-square(6) 95 % point) of ``cov_x_6x6_verdict``, with
its exact binomial 95 % interval, and of the model's ``cov_x_6x6``; median error (deg, mm); the ratio of
RMS errors to an ML estimator that knows the true noise model (refine_poses with the true tracker sigmas
stated, on the clean views; for Student-t views the multivariate t's likelihood at the true scale and
dof) where one exists; the share of fault sessions named by their own finding, the misdiagnoses (with
their codes), the share of sessions with no fail/warn finding, and the verdicts.

    python benchmarks/bench_poseonly_classes.py [--sessions 30] [--classes clean,noise] [--modes eye_in_hand]
        [--first-seed 0] [--workers 2] [--json rows.jsonl] [--rows rows.jsonl]

Sessions run seed by seed over the classes and modes (an interrupted run covers every class), on
``--workers`` Dask worker processes (benchmarks/fanout.py; 1: in this process), each row written to
``--json`` as it comes; ``--rows`` prints the figures of such a file without running. A session takes
1-4 s of one core (20 views, the held-out refits included): 300 per class and mode for the six
coverage classes are 3600 sessions, 1-2 hours on two free cores.

Classes: clean (0.5 mm / 0.1 deg Gaussian), noise (0.2-2 mm, 0.05-0.5 deg), arm_error (DH lengths off by
0.1-0.5 mm, angles by 0.01-0.05 deg, encoders 0.005 deg; no --robot: the pose-only solve takes robot poses as
reported), arm_error_robot (the same sessions calibrated with --robot ARM: the arm's kinematic model, joint
angles by inverse kinematics), arm_error_joints (the same again, each view with its encoder readings as
``joints:``), outliers (2 gross robot or tracker poses), heavy_tails (Student-t, 3 dof),
anisotropic (3-6x along the optical axis), scale (x1.2-2 or its inverse), drift (1-4 mm per view from view
6-14), degenerate (UR arm, joints 2-4 only), time_offset (extra: 0.2-1 % of the move to the next configuration).

Measured (2-core machine shared, 1-2 workers, 1-4 s per session). The figures down to the last block were
taken with Satterthwaite's factor on X's covariance (6 F_0.95(6, nu) / chi2_0.95(6), 1.05-1.08 for 20 views);
the last block is the resampled factor that replaced it (refine/tracker_dof.py). The report prints the same
covariance, so this ellipsoid is its 95 % region. Gaussian classes, 100 sessions per mode (seeds 0-99),
coverage of the verdict covariance (= the model's in every session: the held-out refits never found the spread
beyond chance), mean squared Mahalanobis (chi-square(6): 6), median error, RMS error / ML (rotation,
translation), share with no fail/warn finding; in brackets the plug-in covariance's before (the same sessions,
the same estimates):

    class        mode  cover          mean m2       median error        / ML        quiet
    clean        in    90.0% (89.0)   6.30 (6.74)   0.036 deg 0.48 mm   1.01 1.03   98 %
    clean        to    99.0% (96.0)   5.60 (5.91)   0.045 deg 0.91 mm   1.02 1.03   99 %
    anisotropic  in    88.0% (82.0)   7.24 (7.72)   0.050 deg 0.72 mm   1.01 1.00   96 %
    anisotropic  to    95.0% (92.0)   6.20 (6.53)   0.054 deg 1.23 mm   1.00 1.00   96 %

The ML estimator that knows the tracker's sigmas (solved from the truth) covers 93, 99, 89 and 96 % of these
sessions: 100 sessions scatter by 2-3 %. On more sessions, refine_poses alone (its covariance is the verdict's
here), coverage with the degrees of freedom (plug-in):

    class        sessions  in             to
    clean        300       91.0% (89.0)   96.3% (94.7)
    anisotropic  300       91.7% (89.0)   96.7% (94.3)
    noise        200       90.5% (89.0)   97.0% (95.0)
    outliers     200       90.0% (86.0)   96.0% (94.0)
    heavy_tails  200       87.5% (86.0)   92.0% (90.0)

Before, with the plug-in covariance, the benchmark on seeds 0-99 gave noise 91.0 / 94.0 %, outliers 85.0 / 93.0 %,
heavy_tails 91.0 / 90.0 % (in / to; errors and findings as now: noise 0.068 deg 0.86 mm / 0.093 deg 1.71 mm, ML
ratio 0.99-1.03; outliers and heavy tails named robot_pose_disagrees in 100 % and ~80 % of their sessions).
Heavy tails stayed below with the Gaussian solve on the kept views; they are now modelled as a multivariate
Student-t (refine/tracker_tails.py, docs/uncertainty.md; figures at the end).

scale_estimated (the tracker's translations x0.5-2, calibrated with --estimate-scale), 50 sessions per mode:

    mode  cover   mean m2  median error        s in 1.96 sigma  median |s/s_true - 1|  median sigma/s  verdicts
    in    88.0%   7.43     0.042 deg 0.62 mm   94.0%            5.1e-4                 7.9e-4          PASS 48 WARN 2
    to    98.0%   5.18     0.049 deg 1.18 mm   96.0%            5.3e-4                 7.9e-4          PASS 19 WARN 31

(no tracker_scale finding or other misdiagnosis in any: the diagnostics see the poses rescaled).

Fault and systematic classes (measured with the plug-in covariance), 30 sessions per mode (misdiagnosis: a
fail/warn code of WRONG other than the class's own):

    class        mode  cover  median error        named                 misdiagnosed           verdicts
    arm_error    in    26.7%  0.080 deg 0.75 mm   -                     0/30                   PASS 30
    arm_error    to    50.0%  0.079 deg 1.23 mm   -                     0/30                   PASS 25 WARN 5
    time_offset  in     0.0%  0.103 deg 4.50 mm   -                     0/30                   PASS 15 WARN 15
    time_offset  to     6.7%  0.089 deg 2.44 mm   -                     1/30 tracker_scale     PASS 4 WARN 24 FAIL 2
    drift        in    30.0%  0.089 deg 7.13 mm   target_drift 96.7%    1/30 board_moved       FAIL 30
    drift        to    30.0%  0.076 deg 7.30 mm   target_drift 100%     0/30                   FAIL 30
    scale        in     0.0%  0.086 deg 114 mm    tracker_scale 100%    0/30
    scale        to     0.0%  0.079 deg 492 mm    tracker_scale 100%    0/30
    degenerate   in     -     (refused)           weak_motion 100%      0/30
    degenerate   to     -     (refused)           weak_motion 100%      0/30

Where the tracker's noise is Gaussian, the error is the ML estimator's (1.00-1.03) and coverage 90-97 % on 200-300
sessions, heavy tails 87.5-92 % before their t model (82-96 % with the plug-in covariance: the three tracker
sigmas estimated from 20 views, the one along the optical axis from about 17 degrees of freedom, make it too small
in eye-in-hand).
Systematic errors (DH errors, a time offset, which about a home configuration acts as a joint scale error, drift)
are far outside the ellipsoid and the held-out refits cannot see them: the error is common to every fold. Drift is
named by its own test when no single move is found (diagnose/drift.py ramp_test; before it, 50.0 % / 63.3 %, the
rest absorbed into the tracker sigma); that test also names a drift in 2 of 100 anisotropic eye-to-hand sessions
(none in 100 clean or anisotropic eye-in-hand, 100 clean eye-to-hand). A DH error mostly passes with the truth
outside the 95 % ellipsoid without --robot (below: with it). Heavy-tailed tracker views are named
robot_pose_disagrees.

The arm_error sessions with the arm's model (--robot ARM), 30 sessions per mode (seeds 0-29, the arm_error
class's sessions; mean m2 of the verdict covariance, = the model's in every session):

    class              mode  cover  mean m2  median error        verdicts
    arm_error          in    26.7%  24.02    0.080 deg 0.75 mm   PASS 30
    arm_error          to    50.0%  15.67    0.079 deg 1.23 mm   PASS 25 WARN 5
    arm_error_robot    in    80.0%   8.63    0.074 deg 0.78 mm   PASS 30
    arm_error_robot    to    96.7%   6.03    0.067 deg 1.23 mm   PASS 10 WARN 20
    arm_error_joints   in    90.0%   7.18    0.073 deg 0.69 mm   PASS 30
    arm_error_joints   to   100.0%   5.46    0.070 deg 1.08 mm   PASS 11 WARN 19

With the DH offsets in the model (24 of them, nearly all held by their prior: the views resolve few) X's
covariance grows by their prior's share, and the truth is inside the 95 % ellipsoid as often as in the clean
class (89 % / 96 %) when the joint angles are recorded. By inverse kinematics of the reported poses the model
was another of the arm's configurations reaching the same pose (for a UR arm, one of eight) in 59 of 60 sessions,
with other Jacobians: 80 % eye-in-hand. The solver now takes the configuration nearest the preset's home (where
the simulated programs run), then each view's nearest the previous one: the joint angles are the recorded ones
in every view of 200 of 200 sessions, and the model is the arm_error_joints one (figures at the end). The class's
DH errors (magnitudes uniform in 0.1-0.5 mm and 0.01-0.05 deg) are 1.07x the arms' stated prior sigma (0.3 mm,
0.03 deg) in RMS: within the linearised model's reach (the Jacobians at the true table differ from the nominal ones
by about 1e-3 relative). The WARNs eye-to-hand are the QA limits on sigma (1 mm) and the predicted error (2 mm),
which the wider covariance now crosses. The error itself barely moves: the DH offsets the views leave at their
prior do not correct X, they only widen its covariance.

After the tracker's tails (refine/tracker_tails.py) and the inverse kinematics' configuration (the arm's home):
the benchmark itself, 89-91 sessions per class and mode (seeds 0-45 and 150-195, two processes, 1.9 s per
session on the shared machine), coverage of the verdict covariance with its exact binomial 95 % interval, RMS
error over the ML estimator's (rotation, translation), fault sessions named by their own finding, misdiagnoses
(a fail/warn code of WRONG other than the class's own), sessions with no fail/warn finding:

    class            mode  n   cover                  / ML        named                misdiagnosed      quiet
    clean            in    91  87.9% [79.4, 93.8]     1.03 1.01   -                    0/91              100 %
    clean            to    91  96.7% [90.7, 99.3]     1.00 1.02   -                    0/91              100 %
    heavy_tails      in    91  92.3% [84.8, 96.9]     1.03 1.03   -                    0/91              98.9 %
    heavy_tails      to    91  96.7% [90.7, 99.3]     1.05 1.07   -                    0/91              98.9 %
    outliers         in    91  91.2% [83.4, 96.1]     1.03 1.02   -                    0/91              0 %
    outliers         to    90  97.8% [92.2, 99.7]     0.98 0.99   -                    0/90              0 %
    arm_error_robot  in    91  86.8% [78.1, 93.0]     -           -                    0/91              100 %
    arm_error_robot  to    91  96.7% [90.7, 99.3]     -           -                    0/91              100 %
    drift            in    89  37.1%                  -           target_drift 91.0%   8/89 board_moved  0 %
    drift            to    89  36.0%                  -           target_drift 94.4%   5/89 board_moved  0 %
    scale            in    89  0.0%                   -           tracker_scale 100%   0/89              0 %
    scale            to    89  0.0%                   -           tracker_scale 100%   0/89              0 %
    degenerate       in    89  (refused)              -           weak_motion 100%     0/89              0 %
    degenerate       to    89  (refused)              -           weak_motion 100%     0/89              0 %

Heavy tails are now kept with their EM weights (robot_pose_disagrees in 1 of 91 sessions per mode, 19 of 23
before) and their error is the t-ML's (1.03-1.07; before, on seeds 0-22, 1.17 in translation); through
refine_poses alone on 250 sessions per mode they cover 94.4 % [90.8, 96.9] and 96.4 % [93.3, 98.3]
(docs/uncertainty.md). The drift class's board_moved calls are made without these changes too (seeds 17 and
37 checked on the main branch: the same call);
the 30-session figure above (1/30) was a lucky draw: this misdiagnosis is open. arm_error_robot eye-in-hand
(86.8 %, n 91) is the recorded-joints model (the joints are the same to 1e-6 rad); its interval includes the
arm_error_joints figure (90 %, n 30). Not run here for want of machine time: noise, anisotropic, arm_error
without --robot, arm_error_joints, time_offset (their solves are Gaussian unless the likelihood-ratio test picks
a t, as in 8 of 300 clean sessions: the figures above stand within that).

300 sessions per class and mode (2026-12-06, ``--sessions 300 --classes clean,noise,outliers,heavy_tails,
anisotropic,arm_error,arm_error_robot --workers 2``, 4200 sessions in 28 min on 2 cores; the drift or step
comparison fitted to the deviations' sizes, diagnose/drift.py), then 100 per class and mode of the fault classes:

    class            mode  n    cover                  / ML        named                misdiagnosed      quiet
    clean            in    300  90.7% [86.8, 93.7]     1.03 1.02   -                    0/300             100 %
    clean            to    300  96.3% [93.5, 98.2]     1.02 1.02   -                    0/300             100 %
    noise            in    300  90.7% [86.8, 93.7]     1.04 1.03   -                    1/300 drift       99.7 %
    noise            to    300  95.3% [92.3, 97.4]     1.02 1.02   -                    1/300 drift       99.7 %
    outliers         in    300  90.3% [86.4, 93.4]     1.03 1.02   -                    0/300             0 %
    outliers         to    300  95.0% [91.9, 97.2]     1.02 1.02   -                    0/300             0 %
    heavy_tails      in    300  94.3% [91.1, 96.7]     1.04 1.03   -                    2/300 drift       97.0 %
    heavy_tails      to    300  96.0% [93.1, 97.9]     1.04 1.05   -                    0/300             97.3 %
    anisotropic      in    300  92.0% [88.3, 94.8]     1.02 1.00   -                    0/300             100 %
    anisotropic      to    300  96.7% [94.0, 98.4]     1.01 1.01   -                    2/300 drift       99.0 %
    arm_error        in    300  21.7% [17.1, 26.8]     -           -                    0/300             100 %
    arm_error        to    300  44.0% [38.3, 49.8]     -           -                    0/300             100 %
    arm_error_robot  in    300  90.7% [86.8, 93.7]     -           -                    0/300             100 %
    arm_error_robot  to    300  96.0% [93.1, 97.9]     -           -                    0/300             100 %
    drift            in    100  -                      -           target_drift 100%    0/100             0 %
    drift            to    100  -                      -           target_drift 100%    0/100             0 %
    scale            in    100  -                      -           tracker_scale 100%   0/100             0 %
    scale            to    100  -                      -           tracker_scale 100%   0/100             0 %
    degenerate       in    100  (refused)              -           weak_motion 100%     0/100             0 %
    degenerate       to    100  (refused)              -           weak_motion 100%     0/100             0 %

The drift class's board_moved calls above are gone. An arm error without --robot is not covered: the held-out
folds are interleaved, so each shares the arm's error (validated sigma used in 0 of 300); with --robot it is.

The arm's stated accuracy (refine/arm_accuracy.py, docs/uncertainty.md): arm_error_accuracy calibrates the
arm_error sessions with --robot-accuracy at the common part of the arm's error (maker_accuracy common=True),
arm_error_datasheet at the whole flange error (common=False); arm_error rows also print the coverage of X in
the arm's own frames (effective_truth). Seeds 0-299 (datasheet: 0-99), 2 workers:

    arm_error           in  300  cover 21.7 % [17.1, 26.8]; X in the arm's own frames 51.3 % [45.5, 57.1]
    arm_error           to  300  cover 44.0 % [38.3, 49.8]; X in the arm's own frames 95.3 % [92.3, 97.4]
    arm_error_accuracy  in  300  cover 98.0 % [95.7, 99.3]  mean m2 4.82  PASS 255 WARN 45
    arm_error_accuracy  to  300  cover 98.0 % [95.7, 99.3]  mean m2 4.49  PASS 7 WARN 293
    arm_error_datasheet in  100  cover 100 % [96.4, 100]    mean m2 2.56
    arm_error_datasheet to  100  cover 99.0 % [94.6, 100]   mean m2 2.74

The resampled factor (refine/tracker_dof.py: the estimation repeated on noise drawn at the session's sigmas,
1.07-1.24 for 20 views), 2026-12-07, ``--sessions 100 --classes clean,noise,anisotropic,heavy_tails,outliers
--workers 2`` (seeds 0-99, 1000 sessions in 354 s), coverage of the verdict covariance and mean m2:

    class        mode  n    cover                 mean m2   / ML        quiet
    clean        in    100  91.0% [83.6, 95.8]    5.81      1.01 1.02   100 %
    clean        to    100  99.0% [94.6, 100]     5.21      1.02 1.03   100 %
    noise        in    100  94.0% [87.4, 97.8]    5.57      1.02 1.03   100 %
    noise        to    100  98.0% [93.0, 99.8]    5.39      1.00 1.00   100 %
    anisotropic  in    100  90.0% [82.4, 95.1]    6.60      1.01 0.99   100 %
    anisotropic  to    100  96.0% [90.1, 98.9]    5.82      1.00 1.00   98 %
    heavy_tails  in    100  97.0% [91.5, 99.4]    5.16      1.02 1.03   99 %
    heavy_tails  to    100  98.0% [93.0, 99.8]    4.91      1.03 1.05   99 %
    outliers     in    100  93.0% [86.1, 97.1]    5.87      1.02 1.02   0 %
    outliers     to    100  97.0% [91.5, 99.4]    5.50      1.01 1.01   0 %

Seeds 0-99 are a hard draw eye-in-hand: refine_poses on the same clean sessions with the true sigmas stated
covers 94 % of them, with the estimated ones 91 %; over seeds 0-599 95.0 % and 94.0 % (92.7 % with
Satterthwaite's factor; docs/uncertainty.md). Errors, findings and verdicts as before the change (it moves
only the covariance). Then once on seeds never used before, ``--first-seed 1000 --classes clean,noise,anisotropic``
(100 each): eye-in-hand 93 / 96 / 94 % (mean m2 6.15 / 6.14 / 6.01), eye-to-hand 95 / 93 / 92 % (6.06 / 6.20 /
6.25); pooled 94.3 % and 93.3 % of 300 per mode.
"""

from __future__ import annotations

import argparse
import functools
import json
import shutil
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from scipy.special import chdtri

ARMS = ("ur3", "ur3e", "ur5", "ur5e", "ur10", "ur10e", "ur16e", "rm65")
UR_ARMS = tuple(a for a in ARMS if a.startswith("ur"))  # three parallel joints (2, 3, 4)
MODES = ("eye_in_hand", "eye_to_hand")
N_VIEWS = 20
#: the finding that names each fault class (degenerate motion: also a refusal with error code motion_one_axis)
OWN = {"degenerate": "weak_motion", "scale": "tracker_scale", "drift": "target_drift"}
WRONG = ("pairs_shuffled", "pairs_shifted", "board_moved", "poses_do_not_fit", "target_drift", "tracker_scale")
WRONG += ("square_size",)


def class_options(name: str, rng: np.random.Generator) -> dict:
    """The simulator options of one session of class ``name`` (drawn from ``rng``)."""
    base = {"arm": str(rng.choice(ARMS)), "sigma_mm": 0.5, "sigma_deg": 0.1}
    if name == "clean":
        return base
    if name == "noise":
        return base | {"sigma_mm": float(rng.uniform(0.2, 2.0)), "sigma_deg": float(rng.uniform(0.05, 0.5))}
    if name in ("arm_error", "arm_error_robot", "arm_error_joints", "arm_error_accuracy", "arm_error_datasheet"):
        return base | {"dh_length_error_mm": (0.1, 0.5), "dh_angle_error_deg": (0.01, 0.05), "encoder_sigma_deg": 0.005}
    if name == "outliers":
        return base | {"outlier_views": 2}
    if name == "heavy_tails":
        return base | {"tracker_dof": 3.0}
    if name == "anisotropic":
        return base | {"axial_factor": float(rng.uniform(3.0, 6.0))}
    if name == "scale":
        return base | {"scale": float(np.exp(rng.choice([-1, 1]) * rng.uniform(np.log(1.2), np.log(2.0))))}
    if name == "drift":
        return base | {"drift_mm_per_view": float(rng.uniform(1.0, 4.0)), "drift_start": int(rng.integers(6, 15))}
    if name == "degenerate":
        return base | {"arm": str(rng.choice(UR_ARMS)), "moving_joints": (1, 2, 3)}
    if name == "time_offset":
        return base | {"time_offset": float(rng.uniform(0.002, 0.01))}
    if name == "scale_estimated":
        return base | {"scale": float(np.exp(rng.uniform(np.log(0.5), np.log(2.0))))}
    raise ValueError(f"unknown class {name!r}")


CLASSES = ("clean", "noise", "arm_error", "outliers", "heavy_tails", "anisotropic", "scale", "drift", "degenerate")
CLASSES += ("arm_error_robot", "arm_error_joints", "arm_error_accuracy", "arm_error_datasheet")
#: classes calibrated with --robot ARM, and the class whose sessions they are
ROBOT_CLASSES = {"arm_error_robot": "arm_error", "arm_error_joints": "arm_error"}
#: calibrated with --robot-accuracy: the arm's accuracy as its maker states it (maker_accuracy)
ACCURACY_CLASSES = {"arm_error_accuracy": "arm_error", "arm_error_datasheet": "arm_error"}
EXTRA = ("time_offset", "scale_estimated")
ESTIMATE_SCALE = {"scale_estimated"}  # calibrated with --estimate-scale
ML_CLASSES = {"clean", "noise", "outliers", "anisotropic", "heavy_tails"}  # a tracker model the ML estimator knows


@functools.lru_cache(maxsize=None)
def maker_accuracy(arm: str, mode: str, common: bool) -> tuple[float, float]:
    """(mm, deg) per axis of the flange pose's error over arms of the arm_error class, as a maker would state it.

    100 arms drawn as the class draws them (DH lengths off by 0.1-0.5 mm, angles by 0.01-0.05 deg), each at 20
    configurations of the sessions' motion program (home +- 25 deg per joint). ``common=False``: the RMS of
    the whole flange error Log(T_nominal^-1 T_true) (a datasheet's accuracy). ``common=True``: the RMS of its part
    common to the workspace at the camera's end of the chain (the constant L or R of the fit T_true = L T_nominal
    R, :func:`constant_error`): R in the flange frame (eye-in-hand), L about the workspace centre (eye-to-hand),
    what robot_accuracy states.
    """
    from handeye.frames import inv_T, se3_adjoint, se3_log
    from handeye.kinematics import T_base_end, load_arm
    from handeye.sim.arm_tracker import HOME_RAD
    from handeye.sim.robot_error import make_kinematic_error

    rng = np.random.default_rng(2026)
    nominal = load_arm(arm)
    opts = class_options("arm_error", np.random.default_rng(0))
    errs = []
    for _ in range(100):
        e = make_kinematic_error(
            rng=rng, arm=arm, length_error_mm=opts["dh_length_error_mm"], angle_error_deg=opts["dh_angle_error_deg"]
        )
        q = HOME_RAD + rng.uniform(-1.0, 1.0, (20, 6)) * np.radians(25.0)
        T_true = e.true.T_base_end(q).reshape(-1, 4, 4)
        T_nom = np.stack([T_base_end(nominal, qi) for qi in q])
        if not common:
            errs += [se3_log(inv_T(a) @ b) for a, b in zip(T_nom, T_true, strict=True)]
            continue
        left, right = constant_error(T_nom, T_true)
        T_c = np.eye(4)
        T_c[:3, 3] = T_nom[:, :3, 3].mean(axis=0)
        errs.append(right if mode == "eye_in_hand" else se3_adjoint(inv_T(T_c)) @ left)
    E = np.array(errs)
    return float(1e3 * np.sqrt(np.mean(E[:, 3:] ** 2))), float(np.degrees(np.sqrt(np.mean(E[:, :3] ** 2))))


def constant_error(T_rep: np.ndarray, T_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(l, r): the constant errors of ``T_true ~ Exp(l) · T_rep · Exp(r)`` (least squares, 1 rad against 33 mm)."""
    from scipy.optimize import least_squares

    from handeye.frames import inv_T, se3_exp, se3_log

    w = np.r_[1.0, 1.0, 1.0, 30.0, 30.0, 30.0]

    def residual(p):
        L, R = se3_exp(p[:6]), se3_exp(p[6:])
        return np.concatenate([w * se3_log(inv_T(b) @ L @ a @ R) for a, b in zip(T_rep, T_true, strict=True)])

    p = least_squares(residual, np.zeros(12)).x
    return p[:6], p[6:]


def effective_truth(ts) -> np.ndarray:
    """X in the arm's own frames: the truth moved by the part of the arm's error that is common to every view.

    The arm's true flange poses fitted as ``L · T_reported · R`` with constant L and R (least squares over the
    views); views of that arm without noise give one exact X, which the data cannot tell from the true one.
    """
    from handeye.frames import inv_T, se3_exp
    from handeye.mounting import mounting
    from handeye.refine.problem import solve_pose_graph

    t, T_rep = ts.truth, ts.T_base_end
    left, right = constant_error(T_rep, t.T_base_end_true)
    T_c = se3_exp(left)[None] @ T_rep @ se3_exp(right)[None]
    if ts.mode == "eye_in_hand":
        C = inv_T(t.T_x_true)[None] @ inv_T(T_c) @ t.T_board_true[None]
    else:
        C = inv_T(t.T_x_true)[None] @ T_c @ t.T_board_true[None]
    m = mounting(ts.mode)
    M = np.stack([m.M_from_T_base_end(T) for T in T_rep])
    cov = np.tile(np.diag([1e-6] * 3 + [1e-8] * 3), (len(C), 1, 1))
    T_x, _, _ = solve_pose_graph(M=M, T_cam_board=C, covariances=cov, T_x0=t.T_x_true, T_board0=t.T_board_true)
    return T_x


def _err(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    from handeye.frames import se3_log

    return se3_log(np.linalg.inv(T_est) @ T_true)


def _m2(xi: np.ndarray, cov) -> float:
    if cov is None:
        return float("nan")
    cov = np.asarray(cov, float)
    try:
        return float(xi @ np.linalg.solve(cov, xi))
    except np.linalg.LinAlgError:
        return float("nan")


def _ml_error(ts) -> np.ndarray:
    """Error of the ML estimator that knows the true noise model, on the views without a gross error.

    refine_poses with the true tracker sigmas stated (Gaussian tracker noise); for a Student-t tracker
    (heavy tails) the multivariate-t likelihood at the true scale and degrees of freedom, by iteratively
    reweighted solves of the pose graph (each view's covariance over (nu + 6) / (nu + m2_i)) from there.
    """
    from handeye.initial import all_methods
    from handeye.mounting import mounting
    from handeye.refine.poseonly import PoseView, refine_poses
    from handeye.refine.problem import solve_pose_graph

    t = ts.truth
    keep = [k for k, v in enumerate(ts.view_ids) if v not in t.outlier_view_ids]
    m = mounting(ts.mode)
    C = ts.T_cam_board[keep]
    B = ts.T_base_end[keep]
    M = np.stack([m.M_from_T_base_end(T) for T in B])
    cf = all_methods(m, C, M)
    views = [PoseView(ts.view_ids[k], C[i], B[i]) for i, k in enumerate(keep)]
    sig = (np.radians(t.sigma_deg), t.sigma_mm / 1e3, t.axial_factor * t.sigma_mm / 1e3)
    start = next((e for e in cf.values() if e.status == "ok"), None)
    if start is None:
        return np.full(6, np.nan)
    res = refine_poses(mode=ts.mode, views=views, T_x0=start.T_x, T_board0=start.T_board, starts=cf, tracker_sigma=sig)
    if res.status != "ok":
        return np.full(6, np.nan)
    if t.tracker_dof is None:
        return _err(res.T_x, t.T_x_true)
    from handeye.factors.pose import pose_residual

    R = C[:, :3, :3]
    cov = np.zeros((len(C), 6, 6))  # the tracker's scale matrix per view, the translation's in the target frame
    cov[:, :3, :3] = np.eye(3) * sig[0] ** 2
    cov[:, 3:, 3:] = np.swapaxes(R, 1, 2) @ np.diag([sig[1] ** 2, sig[1] ** 2, sig[2] ** 2]) @ R
    nu, T_x, T_board = t.tracker_dof, res.T_x, res.T_board
    for _ in range(50):
        r = np.stack(
            [
                pose_residual(T_x=T_x, M=Mi, T_board=T_board, T_cam_board_measured=Ci, jacobians=False)[0]
                for Mi, Ci in zip(M, C, strict=True)
            ]
        )
        m2 = np.einsum("ni,nij,nj->n", r, np.linalg.inv(cov), r)
        w = (nu + 6.0) / (nu + m2)
        T_new, T_board, _ = solve_pose_graph(
            M=M, T_cam_board=C, covariances=cov / w[:, None, None], T_x0=T_x, T_board0=T_board
        )
        step = float(np.linalg.norm(_err(T_x, T_new)))
        T_x = T_new
        if step < 1e-10:
            break
    return _err(T_x, t.T_x_true)


def one(cls: str, mode: str, seed: int) -> dict:
    """Simulate, calibrate and score one session."""
    from handeye.sim.arm_tracker import make_arm_tracker_session
    from handeye.workflow import calibrate_session

    same = ROBOT_CLASSES.get(cls, ACCURACY_CLASSES.get(cls, cls))
    rng = np.random.default_rng([seed, CLASSES.index(same) if same in CLASSES else 100 + EXTRA.index(same)])
    opts = class_options(cls, rng)
    ts = make_arm_tracker_session(mode=mode, n_views=N_VIEWS, seed=seed, **opts)
    tmp = Path(tempfile.mkdtemp(prefix="bench26_"))
    t0 = time.perf_counter()
    try:
        path = ts.write(tmp / "s", state_sigma=False)
        if cls == "arm_error_joints":  # each view's encoder readings, as a controller logs them
            import yaml

            d = yaml.safe_load(path.read_text())
            for v, q in zip(d["views"], ts.truth.joints_reported_rad, strict=True):
                v["joints"] = q.tolist()
            path.write_text(yaml.safe_dump(d, sort_keys=False))
        options = None
        if cls in ROBOT_CLASSES or cls in ESTIMATE_SCALE or cls in ACCURACY_CLASSES:  # as handeye calibrate builds
            from handeye.cli import build_parser
            from handeye.options import options_from_args

            flags = ["--robot", opts["arm"]] if cls in ROBOT_CLASSES else ["--estimate-scale"]
            if cls in ACCURACY_CLASSES:
                stated = maker_accuracy(opts["arm"], mode, cls == "arm_error_accuracy")
                flags = ["--robot-accuracy", *(f"{v:.6g}" for v in stated)]
            options = options_from_args(build_parser().parse_args(["calibrate", str(tmp / "s"), *flags]))
        try:
            calibrate_session(tmp / "s", options=options, out_dir=tmp / "out", report=False)
        except Exception as e:  # noqa: BLE001 - a refused or failed run still writes its result.json
            if not (tmp / "out" / "result.json").exists():
                return {"cls": cls, "mode": mode, "seed": seed, "crash": f"{type(e).__name__}: {e}"}
        r = json.loads((tmp / "out" / "result.json").read_text())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    seconds = time.perf_counter() - t0
    codes = sorted({f["code"] for f in r.get("findings", []) if f.get("severity") in ("fail", "warn")})
    out = {
        "cls": cls,
        "mode": mode,
        "seed": seed,
        "arm": opts["arm"],
        "status": r.get("status"),
        "verdict": r.get("verdict"),
        "error_code": (r.get("error") or {}).get("code"),
        "codes": codes,
        "seconds": seconds,
    }
    ref = r.get("refinement") or {}
    x_name = "T_end_cam" if mode == "eye_in_hand" else "T_base_cam"
    T = ref.get(x_name) or r.get(x_name)
    if r.get("status") == "failed" or T is None:
        return out
    xi = _err(np.asarray(T, float), ts.truth.T_x_true)
    out |= {
        "rot_deg": float(np.degrees(np.linalg.norm(xi[:3]))),
        "trans_mm": float(np.linalg.norm(xi[3:]) * 1e3),
        "m2_verdict": _m2(xi, ref.get("cov_x_6x6_verdict")),
        "m2_model": _m2(xi, ref.get("cov_x_6x6")),
        "sigma_source": ref.get("sigma_source"),
        "robot_model": (ref.get("robot_model") or {}).get("kind"),
        "dof_factor": ref.get("cov_x_dof_factor"),
    }
    if same == "arm_error":  # the X the data can tell: in the arm's own frames
        out["m2_effective"] = _m2(_err(np.asarray(T, float), effective_truth(ts)), ref.get("cov_x_6x6_verdict"))
    if cls in ESTIMATE_SCALE and ref.get("tracker_scale"):
        out |= {"scale_true": ts.truth.scale, "scale": ref["tracker_scale"]["value"]}
        out["scale_sigma"] = ref["tracker_scale"]["sigma"]
    if cls in ML_CLASSES:
        xm = _ml_error(ts)
        out |= {
            "ml_rot_deg": float(np.degrees(np.linalg.norm(xm[:3]))),
            "ml_trans_mm": float(np.linalg.norm(xm[3:]) * 1e3),
        }
    return out


def _share(k: int, n: int) -> str:
    """``k/n`` as a percentage with its exact (Clopper-Pearson) binomial 95 % interval."""
    from scipy.stats import beta

    lo = float(beta.ppf(0.025, k, n - k + 1)) if k > 0 else 0.0
    hi = float(beta.ppf(0.975, k + 1, n - k)) if k < n else 1.0
    return f"{k / n:5.1%} [{lo:.1%}, {hi:.1%}]"


def summarise(rows: list[dict], cls: str, mode: str, q95: float) -> str:
    rs = [r for r in rows if r["cls"] == cls and r["mode"] == mode]
    solved = [r for r in rs if "m2_verdict" in r]
    n = len(rs)
    parts = [f"{cls:<12} {mode:<11} n={n:<3} solved {len(solved):>3}"]
    crashes = sum("crash" in r for r in rs)
    if crashes:
        parts.append(f"CRASHED {crashes}")
    if solved:
        cv = int(sum(r["m2_verdict"] <= q95 for r in solved))
        cm = int(sum(r["m2_model"] <= q95 for r in solved))
        parts.append(f"cover verdict {_share(cv, len(solved))} model {cm / len(solved):5.1%}")
        parts.append(
            f"median err {np.median([r['rot_deg'] for r in solved]):.3f} deg "
            f"{np.median([r['trans_mm'] for r in solved]):.2f} mm"
        )
        parts.append(f"mean m2 {np.mean([r['m2_verdict'] for r in solved]):.2f}")
        eff = [r["m2_effective"] for r in solved if np.isfinite(r.get("m2_effective", np.nan))]
        if eff:
            parts.append(f"cover X in the arm's own frames {_share(int(sum(m <= q95 for m in eff)), len(eff))}")
        validated = sum(r.get("sigma_source") not in (None, "model") for r in solved)
        parts.append(f"validated sigma in {validated}/{len(solved)}")
        if cls in ROBOT_CLASSES:
            parts.append(
                "robot model " + " ".join(f"{k} {v}" for k, v in Counter(r["robot_model"] for r in solved).items())
            )
        ml = [r for r in solved if np.isfinite(r.get("ml_rot_deg", np.nan))]
        if ml:
            rr = np.sqrt(np.mean([r["rot_deg"] ** 2 for r in ml]) / np.mean([r["ml_rot_deg"] ** 2 for r in ml]))
            rt = np.sqrt(np.mean([r["trans_mm"] ** 2 for r in ml]) / np.mean([r["ml_trans_mm"] ** 2 for r in ml]))
            parts.append(f"RMS err / ML: rot {rr:.2f} trans {rt:.2f}")
        sc = [r for r in solved if r.get("scale_sigma")]
        if sc:
            z = np.array([(r["scale"] - r["scale_true"]) / r["scale_sigma"] for r in sc])
            rel = np.array([abs(r["scale"] / r["scale_true"] - 1.0) for r in sc])
            parts.append(
                f"scale: truth within 1.96 sigma {np.mean(np.abs(z) <= 1.959964):5.1%}, median |s/s_true - 1| "
                f"{np.median(rel):.2e}, median sigma/s {np.median([r['scale_sigma'] / r['scale'] for r in sc]):.2e}"
            )
    done = [r for r in rs if "crash" not in r]
    if cls in OWN:
        own = OWN[cls]
        named = [own in r["codes"] or (cls == "degenerate" and r["error_code"] == "motion_one_axis") for r in done]
        parts.append(f"named {own} {np.mean(named):5.1%}" if done else "named -")
    wrong = Counter(c for r in done for c in r["codes"] if c in WRONG and c != OWN.get(cls))
    mis = sum(any(c in WRONG and c != OWN.get(cls) for c in r["codes"]) for r in done)
    parts.append(f"misdiagnosed {mis}/{len(done)}" + (f" {dict(wrong)}" if wrong else ""))
    quiet = np.mean([not r["codes"] for r in done]) if done else float("nan")
    parts.append(f"no finding {quiet:5.1%}")
    verdicts = Counter(str(r.get("verdict")) for r in done)
    parts.append("verdicts " + " ".join(f"{k} {v}" for k, v in sorted(verdicts.items())))
    if cls not in OWN:
        other = Counter(c for r in done for c in r["codes"] if c not in WRONG)
        if other:
            parts.append(f"other findings {dict(other)}")
    return "; ".join(parts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=30, help="sessions per class and mode (default 30)")
    ap.add_argument("--classes", default=",".join(CLASSES), help=f"comma-separated, of {', '.join(CLASSES + EXTRA)}")
    ap.add_argument("--modes", default=",".join(MODES), help="comma-separated mounting modes")
    ap.add_argument("--first-seed", type=int, default=0, help="seed of the first session of each class and mode")
    ap.add_argument("--workers", type=int, default=1, help="Dask LocalCluster workers (1: serial, no Dask)")
    ap.add_argument("--json", help="also write every session's row to this file (JSON lines, as they come)")
    ap.add_argument("--rows", help="summarise the rows of an earlier --json file instead of running sessions")
    a = ap.parse_args()
    classes = [c for c in a.classes.split(",") if c]
    modes = [m for m in a.modes.split(",") if m]
    q95 = float(chdtri(6, 0.05))
    if a.rows:
        rows = [json.loads(line) for line in Path(a.rows).read_text().splitlines() if line.strip()]
        print(f"pose-only sessions: {len(rows)} rows of {a.rows}")
        for c in classes:
            for m in modes:
                if any(r["cls"] == c and r["mode"] == m for r in rows):
                    print(summarise(rows, c, m, q95))
        return
    for c in classes:
        if c not in CLASSES + EXTRA:
            ap.error(f"unknown class {c!r}")
    tasks = [(c, m, s) for s in range(a.first_seed, a.first_seed + a.sessions) for c in classes for m in modes]
    t0 = time.perf_counter()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fanout import ordered_map

    rows = []
    for k, row in enumerate(ordered_map(one, *zip(*tasks, strict=True), workers=a.workers), start=1):
        rows.append(row)
        if a.json:  # every row as it comes: a long run's figures survive an interruption
            with open(a.json, "a" if k > 1 else "w") as fh:
                fh.write(json.dumps(row) + "\n")
        if k % max(1, len(tasks) // 20) == 0:
            print(f"{k}/{len(tasks)} sessions, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    print(
        f"pose-only sessions: {N_VIEWS} views, {a.sessions} per class and mode, tracker sigma estimated; "
        f"{len(rows)} sessions in {wall:.0f} s wall ({np.mean([r.get('seconds', 0) for r in rows]):.2f} s each)"
    )
    for c in classes:
        for m in modes:
            print(summarise(rows, c, m, q95))


if __name__ == "__main__":
    main()
