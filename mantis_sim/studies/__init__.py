"""Design studies on the simulator: the sweep over designs (Dask, Parquet), its accuracy
choice, the sweep's figures, and the report of one strike. Dask and pyarrow are the optional
`studies` extra, imported only when a sweep runs or reads its table."""
