"""The model against the robot's real strikes: the strikes as the lab recorded them
(`strikes`), each simulated at its own conditions and compared (`fidelity`, `compare_plots`),
the scene parameters fitted to them (`identify`), a recording day's own state (`day_state`),
the spread fitted to them (`spread_fit`) and judged as forecasts (`forecast`), and the findings
of docs/fidelity.md (`findings`)."""
