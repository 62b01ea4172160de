"""A reader of sequence metafiles, written for the tests from the format's description and independent of snreg's
writer: PLUS's "Sequence file" (pluslib.readthedocs.io, file-formats/FileSequenceFile.html) on MetaIO's header.

What it takes from there: ``Field = Value`` header lines; ``ObjectType = Image`` first; ``NDims = 3``; ``BinaryData =
True``; ``BinaryDataByteOrderMSB = False``; ``DimSize`` with the number of frames last; ``ElementDataFile`` the last
field, ``LOCAL`` meaning the pixel data follows it in the same file (none here: the image is 0 x 0 per frame); frame
fields ``Seq_Frame<FrameIndex>_<Field> = Value``, the first frame 0; a transform under ``<From>To<To>Transform`` as
its 16 numbers row by row, with ``<From>To<To>TransformStatus`` OK or INVALID; ``Timestamp`` in seconds.

And what 3D Slicer's reader of these files (vtkMRMLLinearTransformSequenceStorageNode, read in Slicer's source)
needs beyond that: lines under 1000 characters (it reads them with ``fgets`` into a buffer of that size), and frame
timestamps that stay distinct once rounded to milliseconds (they become the sequence's index values).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

ELEMENT_BYTES = {"MET_UCHAR": 1, "MET_CHAR": 1, "MET_USHORT": 2, "MET_SHORT": 2, "MET_FLOAT": 4, "MET_DOUBLE": 8}
SLICER_LINE_LIMIT = 1000


@dataclass
class SequenceMetafile:
    header: dict[str, str]              # the fields that are not frame fields, in file order
    frames: list[dict[str, str]]        # per frame, its fields without the ``Seq_Frame<k>_`` prefix
    longest_line: int                   # characters, for Slicer's limit


def read_sequence_metafile(path: Path) -> SequenceMetafile:
    blob = Path(path).read_bytes()
    header, frame_fields, order, longest, offset = {}, {}, [], 0, 0
    while True:
        end = blob.index(b"\n", offset)
        line = blob[offset:end].decode("ascii").rstrip("\r")
        offset, longest = end + 1, max(longest, len(line) + 1)
        field, separator, value = line.partition("=")
        assert separator, f"not a 'Field = Value' line: {line!r}"
        field, value = field.strip(), value.strip()
        order.append(field)
        if field.startswith("Seq_Frame"):
            index, _, name = field[len("Seq_Frame"):].partition("_")
            frame_fields.setdefault(int(index), {})[name] = value
        else:
            header[field] = value
        if field == "ElementDataFile":
            break
    assert order[0] == "ObjectType" and header["ObjectType"] == "Image"
    assert header["NDims"] == "3" and header["BinaryData"] == "True" and header["BinaryDataByteOrderMSB"] == "False"
    size = [int(v) for v in header["DimSize"].split()]
    assert len(size) == 3
    assert sorted(frame_fields) == list(range(size[2])), "frames must be numbered 0 .. DimSize[2] - 1"
    assert header["ElementDataFile"] == "LOCAL"
    assert len(blob) - offset == int(np.prod(size)) * ELEMENT_BYTES[header["ElementType"]], "pixel data size"
    return SequenceMetafile(header, [frame_fields[k] for k in range(size[2])], longest)


def transforms(sequence: SequenceMetafile, name: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``(times (N,) s, matrices (N, 4, 4), statuses)`` of the transform ``name`` (e.g. "ProbeTipToTrocar")."""
    matrices = np.array([[float(v) for v in frame[f"{name}Transform"].split()] for frame in sequence.frames])
    assert matrices.shape[1:] == (16,)
    times = np.array([float(frame["Timestamp"]) for frame in sequence.frames])
    return times, matrices.reshape(-1, 4, 4), [frame[f"{name}TransformStatus"] for frame in sequence.frames]


def slicer_index_values(sequence: SequenceMetafile) -> list[str]:
    """The index values Slicer gives the frames: each timestamp rounded to milliseconds."""
    return [f"{float(frame['Timestamp']):.3f}" for frame in sequence.frames]
