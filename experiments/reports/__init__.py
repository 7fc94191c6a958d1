"""What a run reports: figures and markdown.

* :mod:`experiments.reports.figures`: one figure style (a policy's colour and label everywhere, panel grids).
* :mod:`experiments.reports.scores`: score comparisons (ratios, beating another outside both standard errors).
* :mod:`experiments.reports.mission_report`, :mod:`experiments.reports.noise_models_report`,
  :mod:`experiments.reports.new_place_report`, :mod:`experiments.reports.planning_figures`: the reports and figures
  of the mission, the noise-model comparison, the new-place study and the planning experiments.
* :mod:`experiments.reports.sweep_report`: the markdown report of a ``-m`` sweep, a Hydra callback.
"""
