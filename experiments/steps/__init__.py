"""Steps that several experiments share, and the parts of one experiment too large for its entry point.

* :mod:`experiments.steps.classification`: train the frame classifier, classify rendered sequences.
* :mod:`experiments.steps.noise`: fit HBNI on labelled classifier outputs.
* :mod:`experiments.steps.planning`: run the planner (any preset) and the baselines, score controllers on rollouts.
* :mod:`experiments.steps.planner_comparison`: the planners side by side (package delivery, disaster relief).
* :mod:`experiments.steps.bank`: the held-out output bank of the closed loop, built once and cached;
  :mod:`experiments.steps.on_demand`: more held-out sequences, rendered as far as a process reads them.
* :mod:`experiments.steps.closed_loop`: planned against executed values, stream standard errors, report;
  :mod:`experiments.steps.honesty`: the distribution check and the value test of a planning model;
  :mod:`experiments.steps.execution`: the mission's stage 6, every policy executed in closed loop.
* :mod:`experiments.steps.condition_outputs`: the noise-model comparison's classifier outputs per imaging condition.
* :mod:`experiments.steps.place_variants`: the new-place study's filters, each fitted on what it may use;
  :mod:`experiments.steps.place_photos`: the same filters on photographs under a new camera.
* :mod:`experiments.steps.annotate`: the annotated frames (video, output bag) and PNG strip of a macro-observation
  stream.

Entry points (:mod:`experiments.studies`) import these, never each other; a step imports no entry point.
"""
