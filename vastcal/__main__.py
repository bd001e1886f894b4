"""``python -m vastcal …``: the same command line as the ``vastcal`` script (:func:`vastcal.cli.main`)."""

import sys

from vastcal.cli import main

if __name__ == "__main__":
    sys.exit(main())
