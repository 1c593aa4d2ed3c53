"""The model against the robot's real strikes: the strikes as the lab recorded them
(`strikes`, `strike_inputs`), each simulated at its own conditions and compared (`fidelity`,
`compare_plots`, `compare_run`), the scene parameters fitted to them (`identify`,
`identify_run`), a recording day's own state (`day_state`, `day_state_run`), the spread fitted
to them (`spread_fit`, `spread_run`) and judged as forecasts (`forecast`), and the findings of
docs/fidelity.md (`findings`). The `*_run` modules are the commands' orchestration: `mantis
identify`, `compare` and `day-state` parse their arguments and call them."""
