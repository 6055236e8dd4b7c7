"""imc: the application around the stages. A scenario YAML in, a run's results out.

Top level: the scenario schema (:mod:`imc.scenario`, read by :mod:`imc.yamlload`), one run
end to end (:mod:`imc.pipeline`), atomic file writes (:mod:`imc.io`) and the command line
(:mod:`imc.cli`). Sub-packages, each one concern:

- :mod:`imc.wiring`: one run's models and blocks built from a scenario, its plants, truth,
  blur study, random streams and checkpoints;
- :mod:`imc.outputs`: what a run writes: metrics and tracks, figures, the HTML report, the
  Rerun recording, the loop study's plots;
- :mod:`imc.workflow`: campaigns of runs: sweeps, where they run (Dask), ``expect:`` checks;
- :mod:`imc.studies`: the paper's studies and benchmarks (Table 2, the texture map, the
  flight test, the correlator against its peers).

Arrows run downward only: cli -> workflow -> pipeline -> outputs -> wiring -> scenario, io.
"""
