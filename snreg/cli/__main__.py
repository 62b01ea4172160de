"""``python -m snreg.cli``: the ``snreg`` command (the demo rig starts its IMU simulator this way)."""

import sys

from snreg.cli import main

if __name__ == "__main__":
    sys.exit(main())
