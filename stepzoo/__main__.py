"""`python -m stepzoo`: the same as the `stepzoo` command."""
import sys

from stepzoo.cli import main

sys.exit(main())
