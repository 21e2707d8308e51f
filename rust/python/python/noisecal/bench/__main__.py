"""``python -m noisecal.bench``: the same as the ``noisecal-bench`` command."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
