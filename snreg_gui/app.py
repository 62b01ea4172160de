"""``snreg-gui``: start the desktop app (``--demo`` for the hardware-free phantom demo)."""

from __future__ import annotations

import argparse
import sys

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QApplication, QLabel, QMainWindow

from snreg import __version__


class MainWindow(QMainWindow):
    """The main window. Acquisition, wizards and the registration panel arrive with issue 6."""

    def __init__(self, session_path: str | None = None, demo: bool = False):
        super().__init__()
        mode = "demo" if demo else (session_path or "no session")
        self.setWindowTitle(f"snreg {__version__} - {mode}")
        text = QLabel("snreg\n\nThe acquisition screen is not built yet.\n"
                      "Use the command line meanwhile: snreg register, snreg simulate, snreg bench.")
        text.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.setCentralWidget(text)
        self.resize(900, 600)
        self.statusBar().showMessage("demo mode: no hardware" if demo else "ready")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="snreg-gui", description="snreg acquisition app")
    parser.add_argument("--demo", action="store_true", help="simulated devices, no hardware")
    parser.add_argument("session", nargs="?", help="session file to open (.h5)")
    args = parser.parse_args(argv)
    app = QApplication.instance() or QApplication(sys.argv[:1])
    window = MainWindow(args.session, demo=args.demo)
    window.show()
    return app.exec()


if __name__ == "__main__":
    sys.exit(main())
