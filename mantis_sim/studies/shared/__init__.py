"""What the studies share, beside them: the Dask map and its progress line (`parallel`), BLAS on
one thread in a process that simulates for a study (`blas`), CSV tables (`csv_table`), results
with no NaN for JSON or YAML (`finite_values`). The
command line imports the map from here directly; the simulator (mantis_sim's top level) takes a
map as an argument and imports nothing from the studies."""
