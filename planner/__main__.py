"""`python -m planner`: the `planner` command."""
import sys

from .cli import main

sys.exit(main())
