"""The repository explains itself: no tracked file points at a folder beside the clone (the shared one two dots
up) or cites the old design notes file by name or section sign, which a clone does not have; the design is
docs/design.md, cited by section name ("docs/design.md, Contracts: Session")."""

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# the patterns are written so that this file's own source does not match them
OUTSIDE = re.compile(r"\.\./shared|DESIGN(\.md)?\s*§|DESIGN\.md")


def tracked_text_files() -> dict[str, str]:
    names = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    files = {}
    for name in filter(None, names.decode().split("\0")):
        path = ROOT / name
        if not path.is_file():          # deleted in the work tree, not yet committed
            continue
        data = path.read_bytes()
        if b"\0" in data:               # binary: images, DICOM
            continue
        files[name] = data.decode("utf-8", errors="replace")
    return files


def test_there_are_tracked_files_to_check():
    files = tracked_text_files()
    assert "README.md" in files and "docs/design.md" in files and len(files) > 100


def test_the_pattern_catches_what_it_should():
    for text in ("see ../" + "shared/data", "(DESIGN" + " §4)", "DESIGN" + ".md §3's", "in DESIGN" + ".md"):
        assert OUTSIDE.search(text), text
    assert not OUTSIDE.search("docs/design.md, Contracts: Session")


def test_no_tracked_file_refers_outside_the_repository():
    offending = sorted(f"{name}:{text[:match.start()].count(chr(10)) + 1}: {match.group(0)}"
                       for name, text in tracked_text_files().items() for match in OUTSIDE.finditer(text))
    assert not offending, "these files refer outside the repository:\n" + "\n".join(offending)
