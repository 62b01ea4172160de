"""snreg_gui: the PySide6 + pyqtgraph desktop app. It shows and orchestrates; ``snreg`` computes."""
