"""Synthetic data with known ground truth: scenarios, sessions, images and simulated devices.

This part sits beside the core: no core module imports it (only the CLI, the tests and the
benchmarks). Modules: :mod:`~handeye.sim.scenarios` (rigs, view poses, noise), :mod:`~handeye.sim.corners`
(corner-level sessions), :mod:`~handeye.sim.render` (images through OpenCV's lens model),
:mod:`~handeye.sim.vendor` (vendor folders with ground_truth.json), :mod:`~handeye.sim.devices` and
:mod:`~handeye.sim.realman_emulator` (simulated arm and camera), :mod:`~handeye.sim.fleet`.

See docs/simulation.md.
"""
