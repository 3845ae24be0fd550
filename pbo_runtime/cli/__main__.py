"""`python -m pbo_runtime.cli`: the same as `pbo`."""

import sys

from pbo_runtime.cli.main import main

sys.exit(main())
