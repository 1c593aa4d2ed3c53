"""`python -m mantis_sim.fast`: compile the fast engine into its cache now (scripts/bootstrap.sh
does, so that the first simulation of a fresh checkout does not wait for the compiler)."""
from . import warm_up

print(f'mantis_sim.fast: the engine is compiled and cached ({warm_up():.1f} s)')
