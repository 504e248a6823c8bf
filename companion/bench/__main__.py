"""``python -m companion.bench`` = ``companion bench``."""

import sys

from companion.bench.cli import run

sys.exit(run())
