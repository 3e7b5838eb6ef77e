"""Synthetic data with known ground truth: scenarios, sessions, images and simulated devices.

This part sits beside the core: it builds on handeye's modules, and no core module imports it
(only the CLI, the tests and the benchmarks do).

* :mod:`~handeye.sim.scenarios` - default camera and target, seeded random streams, plausible rigs
  per mounting mode, view poses that show (or hide) the board, robot pose noise and outliers.
* :mod:`~handeye.sim.corners` - :class:`CornerSession` / :func:`make_corner_session`: corners projected
  through the truth, with pixel noise, robot noise, outliers and hidden views; no images.
* :mod:`~handeye.sim.render` - anti-aliased images of a chessboard or ChArUco board through OpenCV's
  lens model (inverse mapping of every sub-pixel sample).
* :mod:`~handeye.sim.vendor` - :func:`write_vendor_session`: a corner session rendered and written
  in the vendor layout (N.jpg, poses.txt, config.yaml) with ground_truth.json.
* :mod:`~handeye.sim.devices` - a simulated arm and camera for ``handeye collect --robot sim``.
* :mod:`~handeye.sim.realman_emulator` - a TCP server speaking the RealMan arm's JSON protocol.
"""
