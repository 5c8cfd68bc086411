"""`python -m pipelines.cli ...` runs the `seeu` command (also under torchrun: `-m pipelines.cli train ...`)."""

import sys

from pipelines.cli import main

sys.exit(main())
