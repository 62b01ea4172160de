"""Qt-free coordination that the app and the command line share: the acquisition loop's steps, a registration run
and its exports, the calibration wizards' live capture loops, frames made ready for display.

The GUI runs these in its worker threads and only shows what they return; ``snreg demo --headless`` runs the
same code without a window.
"""
