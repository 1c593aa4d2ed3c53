"""Studies of many strikes on the simulator of one (mantis_sim's top level), which imports
nothing from here. One folder per what a study serves:

- `design/`: design studies, the designs a robot could have: the sweep over scene parameters
  (Dask, Parquet), its accuracy choice and the solvers' benchmark, the sweep's figures, how the
  spread blurs a design's effects, and the report of one simulated strike.
- `real_strikes/`: the model against the robot's real strikes: reading them, the comparison,
  the identification, a day's state, the spread's fit and forecasts, and the findings of
  docs/fidelity.md.
- `rig_study/`: studies run on the rig, judged against the twin.
- `shared/`: the machinery the studies share: the Dask map, BLAS on one thread, CSV tables.

Dask and pyarrow are the optional `studies` extra, imported only when a study runs on Dask or
reads its table.
"""
