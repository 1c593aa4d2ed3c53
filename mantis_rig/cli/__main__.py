"""`python -m mantis_rig.cli`: the `mantis` command."""
import sys

from .main import main

sys.exit(main())
