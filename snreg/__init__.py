"""snreg: link preoperative SPECT/CT sentinel nodes to nodes stored during surgery.

The core library. It never imports Qt; the GUI lives in ``snreg_gui``.
"""

__version__ = "0.1.0"
