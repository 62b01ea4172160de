import sys

from snreg_gui.app import main

sys.exit(main())
