"""snreg_gui: the PySide6 + pyqtgraph desktop app. It shows and orchestrates; ``snreg`` computes."""

import pyqtgraph as pg

pg.setConfigOptions(imageAxisOrder="row-major")     # images are (H, W[, 3]) arrays, as OpenCV and numpy give them
