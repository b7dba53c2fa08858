"""The validation wing: what checks the science from outside the nightly job.

* :mod:`.montecarlo`: the Monte Carlo validity study of the estimators (bias, spread
  against the stated u, coverage, var/CRB), ``accelcal montecarlo``;
* :mod:`.diagnosis_benchmark`: the diagnosis scored on simulated campaigns with realistic
  DAQ noise and on the dev set, ``accelcal diagnose-benchmark``;
* :mod:`.simruns`: simulated runs as the science sees a parsed run file.

The lab's pipeline (flows, tasks, estimators, diagnosis) imports nothing from here.
"""
