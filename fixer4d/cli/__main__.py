"""`python -m fixer4d.cli VERB ...`: the `fixer4d` command without the installed script."""
import sys

from fixer4d.cli import main

sys.exit(main())
