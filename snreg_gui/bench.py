"""``python -m snreg_gui.bench``: GUI-thread stalls during demo acquisition (:mod:`snreg_gui.tools.bench`)."""

import sys

from snreg_gui.tools.bench import main

if __name__ == "__main__":
    sys.exit(main())
