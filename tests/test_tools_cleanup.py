"""The GUI bench leaves nothing behind without --keep (its session, journal, videos and SPECT went to a temp folder
after every run)."""

from __future__ import annotations

import tempfile

import pytest

pytest.importorskip("pytestqt")

from snreg_gui.tools import bench  # noqa: E402


def test_the_bench_removes_what_it_wrote(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    written = []

    def run(args, app, work):
        for name in ("bench.h5", "bench.h5.journal", "bench.left.mkv", "bench.right.mkv", "bench-spect.dcm"):
            (work / name).write_bytes(b"x" * 100)
        written.append(work)
        return 0
    monkeypatch.setattr(bench, "_run", run)
    assert bench.main(["--seconds", "1"]) == 0
    assert written and not written[0].exists() and list(tmp_path.iterdir()) == []
