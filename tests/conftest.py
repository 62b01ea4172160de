"""Shared fixtures. Qt runs offscreen; every random process is seeded."""

import os
import tempfile

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
# QSettings (recent files, window layout, devices) of the app under test never touch the user's own.
os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="snreg-test-config-")

import numpy as np
import pytest


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture
def pelvic_nodes():
    """Six well-separated nodes (mm) spread like a pelvic SN pattern, with station labels."""
    xyz = np.array([[-55.0, 20.0, 30.0], [-45.0, 42.0, 8.0], [-47.0, 78.0, 50.0],
                    [52.0, 18.0, 35.0], [44.0, 45.0, 12.0], [12.0, 100.0, 72.0]])
    labels = ["EXT R", "OBT R", "INT R", "EXT L", "OBT L", "SAC L"]
    return xyz, labels
