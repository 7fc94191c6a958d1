"""Steps that several experiments share, one module per stage of the pipeline.

* :mod:`experiments.steps.perception`: train the frame classifier, classify rendered sequences.
* :mod:`experiments.steps.noise`: fit HBNI on labelled classifier outputs.
* :mod:`experiments.steps.planning`: run G-DICE and the baselines, score controllers on rollouts.
* :mod:`experiments.steps.planning_figures`: the planning experiments' figures.

Entry points (``conf/experiment/*.yaml`` ``entry``) import these, never each other.
"""
