"""The IMU line protocol and stream decoder: round trips, corrupt lines, gap counting (docs/design.md, Contracts)."""

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from snreg.imu.protocol import (DEFAULT_ODR_HZ, MAX_LINE_BYTES, CorruptLine, ImuSample, InfoLine, StreamCounts,
                                StreamDecoder, checksum, format_info, format_line, parse_line)
from snreg.imu.reader import DEFAULT_BAUD

FIRMWARE = Path(__file__).resolve().parents[1] / "resources" / "firmware"


def test_a_known_line_and_its_checksum():
    line = format_line(1234, [0.0, -0.000122, 1.000034], [0.004375, -125.0, 0.0])
    assert line == b"$IMU,1234,0.000000,-0.000122,1.000034,0.004375,-125.000000,0.000000*7D\r\n"
    body = line[1:line.index(b"*")]
    assert checksum(body) == 0x7D and checksum(b"") == 0 and checksum(b"AB") == ord("A") ^ ord("B")
    sample = parse_line(line, t_host_ns=42)
    assert isinstance(sample, ImuSample)
    assert (sample.t_host_ns, sample.t_device_us) == (42, 1234)
    np.testing.assert_array_equal(sample.accel_g, [0.0, -0.000122, 1.000034])
    np.testing.assert_array_equal(sample.gyro_dps, [0.004375, -125.0, 0.0])
    assert not sample.accel_g.flags.writeable


def test_lowercase_checksum_surrounding_whitespace_and_blank_lines():
    line = format_line(7, [0, 0, 1], [0, 0, 0]).strip()
    assert isinstance(parse_line(b"  \r" + line[:-2] + line[-2:].lower() + b"\r\n"), ImuSample)
    assert parse_line(b"") is None and parse_line(b" \r\n") is None


def test_info_line_and_its_rate():
    info = parse_line(format_info(208))
    assert info == InfoLine("snreg-imu 1 LSM6DSOX odr_hz=208")
    assert info.odr_hz == 208.0
    assert InfoLine("snreg-imu 1 replay odr_hz=99.21").odr_hz == pytest.approx(99.21)
    assert InfoLine("hello").odr_hz is None and InfoLine("odr_hz=0").odr_hz is None


GOOD = format_line(1000, [0.1, 0.2, 0.9], [1.0, -2.0, 3.0]).strip()


def _framed(body: bytes) -> bytes:
    return b"$" + body + b"*%02X" % checksum(body)


@pytest.mark.parametrize("raw, reason", [
    (GOOD[:-1] + (b"0" if GOOD[-1:] != b"0" else b"1"), "checksum mismatch"),
    (GOOD.replace(b"0.1", b"0.3", 1), "checksum mismatch"),
    (GOOD[:30], "no $...*checksum frame (truncated?)"),
    (GOOD[:-3], "no $...*checksum frame (truncated?)"),
    (b"\x00\xff\xfe binary \x10", "not a protocol line"),
    (b"IMU,1,0,0,0,0,0,0*00", "not a protocol line"),
    (_framed(b"IMU,1,0,0,x,0,0,0"), "not $IMU with a time and six numbers"),
    (_framed(b"IMU,1,0,0,1,0,0"), "not $IMU with a time and six numbers"),
    (_framed(b"IMU,1,0,0,1,0,0,0,0"), "not $IMU with a time and six numbers"),
    (_framed(b"IMU,1,0,0,nan,0,0,0"), "not $IMU with a time and six numbers"),
    (_framed(b"IMU,1,0,0,inf,0,0,0"), "not $IMU with a time and six numbers"),
    (_framed(b"IMU,1,0,0,1e999,0,0,0"), "non-finite value"),
    (_framed(b"IMU,-1,0,0,1,0,0,0"), "not $IMU with a time and six numbers"),
    (_framed(b"IMU,4294967296,0,0,1,0,0,0"), "device time beyond 32 bits"),
    (_framed(b"IMX,1,0,0,1,0,0,0"), "not $IMU with a time and six numbers"),
    (_framed(b"IMU,1,0,0,1,0,0,\xb5"), "not $IMU with a time and six numbers"),
    (b"# caf\xe9", "information line is not UTF-8"),
    (b"$" + b"9" * MAX_LINE_BYTES, f"longer than {MAX_LINE_BYTES} bytes"),
])
def test_corrupt_lines_are_reported_not_raised(raw, reason):
    item = parse_line(raw)
    assert isinstance(item, CorruptLine) and item.reason == reason


def test_format_refuses_what_the_protocol_cannot_carry():
    with pytest.raises(ValueError, match="finite"):
        format_line(0, [np.nan, 0, 0], [0, 0, 0])
    with pytest.raises(ValueError, match="2\\*\\*32"):
        format_line(1 << 32, [0, 0, 0], [0, 0, 0])


finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(t_us=st.integers(0, (1 << 32) - 1), accel=st.lists(finite, min_size=3, max_size=3),
       gyro=st.lists(finite, min_size=3, max_size=3), decimals=st.integers(0, 9))
def test_any_valid_sample_survives_format_and_parse_within_its_printed_precision(t_us, accel, gyro, decimals):
    sample = parse_line(format_line(t_us, accel, gyro, decimals))
    assert isinstance(sample, ImuSample) and sample.t_device_us == t_us
    tolerance = 0.5 * 10.0 ** -decimals + 1e-9
    assert np.all(np.abs(sample.accel_g - accel) <= tolerance)
    assert np.all(np.abs(sample.gyro_dps - gyro) <= tolerance)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400))
def test_arbitrary_bytes_never_raise(raw):
    assert isinstance(parse_line(raw), ImuSample | InfoLine | CorruptLine | type(None))


line_material = st.one_of(
    st.binary(max_size=300).map(lambda b: b.replace(b"\n", b"")),
    st.builds(lambda t, v: format_line(t, v[:3], v[3:]).strip(), st.integers(0, (1 << 32) - 1),
              st.lists(st.floats(-10, 10), min_size=6, max_size=6)),
    st.text(max_size=40).map(lambda s: ("#" + s).replace("\n", "").encode("utf-8")),
)


@settings(max_examples=200, deadline=None)
@given(lines=st.lists(line_material, max_size=20), cuts=st.lists(st.integers(0, 5000), max_size=6))
def test_decoder_counts_every_line_that_is_not_valid_as_corrupt_whatever_the_chunking(lines, cuts):
    stream = b"".join(line + b"\n" for line in lines)
    decoder = StreamDecoder(rate_hz=208.0)
    items, start = [], 0
    for cut in sorted(c % (len(stream) + 1) for c in cuts) + [len(stream)]:
        items += decoder.feed(stream[start:cut], t_host_ns=0)
        start = cut
    parsed = [parse_line(line) for line in lines]
    assert decoder.counts.corrupt == sum(isinstance(p, CorruptLine) for p in parsed)
    assert decoder.counts.samples == sum(isinstance(p, ImuSample) for p in parsed)
    assert [type(i) for i in items] == [type(p) for p in parsed if isinstance(p, ImuSample | InfoLine)]


def _lines(times_us, rate_hz=1000.0):
    return b"".join(format_line(t % (1 << 32), [0, 0, 1], [0, 0, 0]) for t in times_us)


def test_gaps_count_missing_samples_across_the_wrap_and_restarts_count_nothing():
    decoder = StreamDecoder(rate_hz=1000.0)
    start = (1 << 32) - 2500
    times = [start + 1000 * k for k in range(10)]            # crosses the 32-bit wrap after 3 samples
    del times[5:8]                                            # 3 missing
    times += [times[-1] + 1400, times[-1] + 2400]             # jitter below 1.5 periods: no drop
    decoder.feed(_lines(times), 0)
    assert decoder.counts == StreamCounts(samples=9, corrupt=0, dropped=3)
    decoder.feed(_lines([5_000, 6_000]), 0)                   # device restarted: time went back
    decoder.feed(_lines([6_000 + 3_000_000]), 0)              # 3 s of silence: a restart, not 2999 drops
    assert decoder.counts == StreamCounts(samples=12, corrupt=0, dropped=3)


def test_rate_comes_from_the_info_line_unless_given():
    decoder = StreamDecoder()
    assert decoder.rate_hz == DEFAULT_ODR_HZ
    decoder.feed(format_info(1000) + _lines([0, 2000]), 0)
    assert decoder.rate_hz == 1000.0 and decoder.counts.dropped == 1
    assert StreamDecoder(rate_hz=50.0).rate_hz == 50.0
    with pytest.raises(ValueError, match="positive"):
        StreamDecoder(rate_hz=0)


def test_a_sample_whose_dollar_became_a_hash_leaves_the_rate():
    """A '$' corrupted to '#' reads as an information line; only one that states odr_hz may set the rate
    (before, it reset the rate, and the samples after it were counted against the wrong period)."""
    decoder = StreamDecoder()
    corrupted = b"#" + format_line(1000, [0, 0, 1], [0, 0, 0])[1:]
    decoder.feed(format_info(1000) + _lines([0]) + corrupted + _lines(1000 * np.arange(2, 102)), 0)
    assert decoder.rate_hz == 1000.0 and decoder.info.odr_hz == 1000.0
    assert decoder.counts == StreamCounts(samples=101, corrupt=0, dropped=1)    # the one sample lost, no more


def test_an_endless_line_counts_once_and_the_stream_recovers():
    decoder = StreamDecoder(rate_hz=1000.0)
    for _ in range(10):
        decoder.feed(b"\xaa" * 100, 0)
    decoder.feed(b"\n" + _lines([0, 1000]), 0)
    assert decoder.counts == StreamCounts(samples=2, corrupt=1, dropped=0)
    decoder.feed(b"$IMU,12,0,0", 0)
    decoder.resync()                                          # a reconnect forgets the partial line
    decoder.feed(_lines([50_000]), 0)
    assert decoder.counts == StreamCounts(samples=3, corrupt=1, dropped=0)


def test_the_firmware_speaks_this_protocol():
    sketch = (FIRMWARE / "snreg_imu" / "snreg_imu.ino").read_text(encoding="utf-8")
    info = parse_line(re.search(r'INFO\[\] = "(.*?)";', sketch).group(1).encode())
    assert isinstance(info, InfoLine) and info.odr_hz == 208.0
    assert f"BAUD = {DEFAULT_BAUD};" in sketch
    assert "LSM6DS_ACCEL_RANGE_4_G" in sketch and "LSM6DS_GYRO_RANGE_125_DPS" in sketch
    example = re.search(r"^\$IMU,.*$", (FIRMWARE / "README.md").read_text(encoding="utf-8"), flags=re.M).group(0)
    assert isinstance(parse_line(example.encode()), ImuSample)
