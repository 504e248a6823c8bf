"""``python -m companion.bench`` = ``companion bench``."""

import sys

from companion.cli.bench import run

sys.exit(run())
