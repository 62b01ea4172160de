"""A NRRD reader written for the tests from the format's specification (http://teem.sourceforge.net/nrrd/format.html),
independent of snreg's writer: attached data only, raw or gzip encoding."""

import gzip
from pathlib import Path

import numpy as np

TYPES = {"double": "f8", "float": "f4", "int": "i4", "short": "i2", "uchar": "u1", "unsigned char": "u1"}


def read_nrrd(path: Path) -> tuple[dict, dict, np.ndarray]:
    """``(fields, keys, array)``: the magic line, then ``field: value`` and ``key:=value`` lines (``#`` comments)
    up to the first empty line, then the data in ``type``, ``endian`` and ``encoding``; ``sizes`` lists the axes
    fastest first, so the array's shape is ``sizes`` reversed."""
    blob = Path(path).read_bytes()
    end = blob.index(b"\n\n")
    lines = blob[:end].decode("ascii").split("\n")
    assert lines[0].startswith("NRRD000"), lines[0]
    fields, keys = {}, {}
    for line in lines[1:]:
        if line.startswith("#"):
            continue
        if ":=" in line:
            key, value = line.split(":=", 1)
            keys[key] = value
        else:
            field, value = line.split(": ", 1)
            fields[field] = value
    data = blob[end + 2:]
    if fields["encoding"] in ("gzip", "gz"):
        data = gzip.decompress(data)
    else:
        assert fields["encoding"] == "raw", fields["encoding"]
    dtype = np.dtype(("<" if fields.get("endian", "little") == "little" else ">") + TYPES[fields["type"]])
    sizes = [int(v) for v in fields["sizes"].split()]
    assert int(fields["dimension"]) == len(sizes)
    assert len(data) == int(np.prod(sizes)) * dtype.itemsize
    return fields, keys, np.frombuffer(data, dtype=dtype).reshape(sizes[::-1])


def read_metafile_transforms(path: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(times, matrices)`` of a sequence metafile's ``Seq_Frame<k>_<name>Transform = 16 numbers`` (row by row) and
    ``Seq_Frame<k>_Timestamp`` lines, in frame order."""
    frames: dict[int, dict] = {}
    for line in Path(path).read_text(encoding="ascii").splitlines():
        key, _, value = line.partition(" = ")
        if not key.startswith("Seq_Frame"):
            continue
        number, field = key[len("Seq_Frame"):].split("_", 1)
        frames.setdefault(int(number), {})[field] = value
    order = sorted(frames)
    assert all(frames[k][f"{name}TransformStatus"] == "OK" for k in order)
    matrices = np.array([[float(v) for v in frames[k][f"{name}Transform"].split()] for k in order]).reshape(-1, 4, 4)
    return np.array([float(frames[k]["Timestamp"]) for k in order]), matrices
