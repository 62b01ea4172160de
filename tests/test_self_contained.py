"""The repository explains itself: no tracked file points at a path outside it (``../shared``) or cites the
design notes by a section sign of a file a clone does not have; the design is docs/design.md."""

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = ("../shared", "DESIGN " + "§")   # split so this file does not match itself


def tracked_text_files() -> dict[str, str]:
    names = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    files = {}
    for name in filter(None, names.decode().split("\0")):
        path = ROOT / name
        if not path.is_file():          # deleted in the work tree, not yet committed
            continue
        data = path.read_bytes()
        if b"\0" in data:               # binary: images, DICOM, PNG
            continue
        files[name] = data.decode("utf-8", errors="replace")
    return files


def test_there_are_tracked_files_to_check():
    files = tracked_text_files()
    assert "README.md" in files and "docs/design.md" in files and len(files) > 100


def test_no_tracked_file_refers_outside_the_repository():
    offending = sorted(f"{name}: {needle!r}" for name, text in tracked_text_files().items()
                       for needle in FORBIDDEN if needle in text)
    assert not offending, "these files refer outside the repository:\n" + "\n".join(offending)
