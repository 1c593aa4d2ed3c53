"""Design studies: the designs a robot could have, simulated. Designs and their rows
(`designs`), the sweep over them on Dask with its Parquet table (`sweep`), the accuracy a sweep
runs at (`accuracy`) and the solvers' work-precision benchmark (`benchmark`), the sweep's
figures (`plots`), how many strikes a design's effect needs against the spread
(`spread_effects`), and the report of one simulated strike (`strike_report`)."""
