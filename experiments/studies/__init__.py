"""The experiments' entry points, one module per ``conf/experiment/<name>.yaml`` (its ``entry``: ``run(settings,
run_dir) -> metrics``). :mod:`experiments.run` builds the typed settings and calls the entry; an entry point never
imports another (what several share lives in :mod:`experiments.steps`)."""
