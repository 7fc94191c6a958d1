"""Run folders: where runs live, what a run writes and how a finished run is loaded back.

* :mod:`experiments.runs.paths`: the root of runs, sweeps and caches (``HBNI_PYRO_ROOT`` or the working directory).
* :mod:`experiments.runs.outputs`: a run's metrics, figures and report, written atomically.
* :mod:`experiments.runs.status`: ``status.json``, running, completed or failed.
* :mod:`experiments.runs.artifacts`: fitted objects saved with a run, and :func:`~experiments.runs.artifacts.load_run`.
* :mod:`experiments.runs.clock`: a run's stage clock and progress messages.
"""
