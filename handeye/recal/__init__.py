"""Recalibration: check an installed calibration against new data and compare two calibrations.

* :mod:`.compare`  ``compare_results(a, b)``: the difference of two results of one rig, its squared
  Mahalanobis distance under the sum of their covariances and a p-value (``handeye compare``);
* :mod:`.loaded`   reading what a result.json says about X, the intrinsics and their covariances;
* :mod:`.verify`   ``verify_session``: a short session tested against an installed calibration without
  re-solving it (``handeye verify``), and the verification plan (``handeye verify --plan``);
  :mod:`.verification` (the new views refined and tested), :mod:`.joint` and :mod:`.drift` (the test);
* :mod:`.prior`    the earlier result as a prior of a new calibration (``handeye calibrate --prior``).
"""
