"""Data collection: a robot arm and a camera, captured into a native handeye session.

Backends (robot: RealMan JSON over TCP in :mod:`.realman`; camera: RealSense live or a recording in
:mod:`.realsense`) sit behind two small interfaces (:mod:`.robot`, :mod:`.camera`). The capture loop
and its checks are in :mod:`.collector`, the automatic pose plan in :mod:`.plan` (with the board
visibility geometry it shares with the simulator in :mod:`.visibility`), the crash-safe writer in
:mod:`.session_writer`. Thresholds are in configs/collect.yaml. The simulated arm and camera live in
:mod:`handeye.sim.devices` (this package never imports them); the command line that picks the
backends is :mod:`handeye.cli.collect`.
"""
