"""Data collection: a robot arm and a camera, captured into a native handeye session.

Backends (robot: RealMan JSON over TCP, simulated; camera: RealSense live, RealSense recording,
simulated) sit behind two small interfaces (:mod:`.robot`, :mod:`.camera`). The capture loop is in
:mod:`.collector`, the automatic pose plan in :mod:`.plan`, the crash-safe writer in
:mod:`.session_writer`, the command-line glue is :mod:`handeye.cli.collect`.
"""
