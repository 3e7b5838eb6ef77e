"""Many sessions at once: ``handeye batch`` on Dask, resumable, and the fleet index.

* :mod:`~handeye.batch.discover` - the sessions under a root and their installs and times;
* :mod:`~handeye.batch.run` - one Dask task per session (the single command's workflow in a child
  process with a time limit), the skip rule, the batch records;
* :mod:`~handeye.batch.child` - the child process of one session;
* :mod:`~handeye.batch.index` - fleet.csv, index.html and index.md from an output folder alone.

Nothing here is imported by the core; the heavy parts (Dask, the calibration) load where they run.
"""
