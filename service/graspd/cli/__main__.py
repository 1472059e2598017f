"""`python -m graspd.cli`: the graspd command."""

import sys

from graspd.cli.main import main

sys.exit(main())
