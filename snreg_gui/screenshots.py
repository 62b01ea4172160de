"""``python -m snreg_gui.screenshots -o DIR``: every screen of the demo in a real window (:mod:`snreg_gui.tools.screenshots`)."""

import sys

from snreg_gui.tools.screenshots import main

if __name__ == "__main__":
    sys.exit(main())
