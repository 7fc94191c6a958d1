"""Steps that several experiments share, one module per stage of the pipeline.

* :mod:`experiments.steps.classification`: train the frame classifier, classify rendered sequences.
* :mod:`experiments.steps.noise`: fit HBNI on labelled classifier outputs.
* :mod:`experiments.steps.planning`: run the planner (any preset) and the baselines, score controllers on rollouts.
* :mod:`experiments.reports.planning_figures`: the planning experiments' figures.
* :mod:`experiments.steps.planner_comparison`: the planners side by side (package delivery, disaster relief).
* :mod:`experiments.steps.bank`: the held-out output bank of the closed loop, built once and cached.
* :mod:`experiments.steps.closed_loop`: planned against executed values, stream standard errors, report.
* :mod:`experiments.steps.annotate`: the annotated frames (video, output bag) and PNG strip of a macro-observation
  stream.

Entry points (``conf/experiment/*.yaml`` ``entry``) import these, never each other.
"""
