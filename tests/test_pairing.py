"""Left/right pairing by timestamp (thesis §3.4.2): <= 15 ms per pair, skip to get back under 10 ms.

Streams are 30 fps with seeded jitter, dropped frames and clock drift; each frame carries its
own eye and index in its pixels, so the tests know which frames were paired and skipped.
"""

import math
import threading

import numpy as np
import pytest

from snreg.tracking import SkewStats, StereoPairer

PERIOD_MS = 1000.0 / 30.0


def payload(index: int, eye: int) -> np.ndarray:
    return np.array([[[index % 256, index // 256, eye]]], np.uint8)


def ident(image: np.ndarray) -> int:
    return int(image[0, 0, 0]) + 256 * int(image[0, 0, 1])


def streams(n=300, *, jitter_ms=6.0, drift_ms=0.0, drop_left=0.0, drop_right=0.0, seed=0):
    """Left and right (t_ns, index) lists: 30 fps, uniform jitter per frame, right clock late by a growing drift."""
    rng = np.random.default_rng(seed)
    base = np.arange(n) * PERIOD_MS
    t_left = base + rng.uniform(-jitter_ms, jitter_ms, n)
    t_right = base + np.linspace(0.0, drift_ms, n) + rng.uniform(-jitter_ms, jitter_ms, n)
    keep_left, keep_right = rng.random(n) >= drop_left, rng.random(n) >= drop_right
    left = [(round(t * 1e6), i) for i, t in enumerate(t_left) if keep_left[i]]
    right = [(round(t * 1e6), i) for i, t in enumerate(t_right) if keep_right[i]]
    return left, right


def feed(pairer, left, right):
    """Push both eyes in arrival (time) order, as two capture threads would; the emitted pairs."""
    events = sorted([(t, 0, i) for t, i in left] + [(t, 1, i) for t, i in right])
    pairs = []
    for t, eye, i in events:
        pairs += pairer.push_left(t, payload(i, 0)) if eye == 0 else pairer.push_right(t, payload(i, 1))
    return pairs


def indices(pairs):
    return [(ident(p.left), ident(p.right)) for p in pairs]


def times_ms(pairs):
    return [(p.t_left_ns / 1e6, p.t_right_ns / 1e6) for p in pairs]


def assert_stats_match(stats: SkewStats, pairs):
    skews = np.array([(p.t_right_ns - p.t_left_ns) / 1e6 for p in pairs])
    assert stats.pairs == len(pairs) == len(skews)
    assert stats.mean_ms == pytest.approx(skews.mean(), abs=1e-9)
    assert stats.std_ms == pytest.approx(skews.std(), abs=1e-9)
    assert stats.max_abs_ms == pytest.approx(np.abs(skews).max(), abs=1e-12)
    assert [p.index for p in pairs] == list(range(len(pairs)))


def assert_consistent(pairer, pairs, left, right):
    """Every pair within 15 ms, each frame used once and in order, and every frame accounted for."""
    assert all(abs(p.t_right_ns - p.t_left_ns) <= 15_000_000 for p in pairs)
    used = np.array(indices(pairs))
    assert np.all(np.diff(used, axis=0) > 0)
    stats, (pending_left, pending_right) = pairer.stats(), pairer.pending
    assert len(pairs) + stats.skipped_left + pending_left == len(left)
    assert len(pairs) + stats.skipped_right + pending_right == len(right)
    assert_stats_match(stats, pairs)


def test_jittered_streams_pair_frame_for_frame_without_skips():
    left, right = streams(jitter_ms=6.0, seed=1)
    pairer = StereoPairer()
    pairs = feed(pairer, left, right)
    assert indices(pairs) == [(i, i) for i in range(300)]
    assert pairer.stats().skipped == 0 and pairer.pending == (0, 0)
    assert pairer.stats().max_abs_ms <= 12.0                   # two +-6 ms jitters
    assert abs(pairer.stats().mean_ms) < 1.0 and 3.0 < pairer.stats().std_ms < 6.0
    assert_consistent(pairer, pairs, left, right)


def test_a_dropped_frame_skips_exactly_the_frame_that_lost_its_partner():
    left, right = streams(jitter_ms=6.0, drop_right=0.05, seed=2)
    dropped = sorted(set(range(300)) - {i for _, i in right})
    assert 5 <= len(dropped) <= 30
    pairer = StereoPairer()
    pairs = feed(pairer, left, right)
    assert indices(pairs) == [(i, i) for _, i in right]
    stats = pairer.stats()
    assert (stats.skipped_left, stats.skipped_right, stats.skipped) == (len(dropped), 0, len(dropped))
    assert_consistent(pairer, pairs, left, right)


def test_drift_skips_only_while_the_offset_crosses_the_gap_between_frames():
    """Right clock drifts 0 -> 40 ms: frame-for-frame pairs while the offset is small, then
    left k with right k-1. Either pairing meets 15 ms only outside roughly 13-20 ms of offset."""
    n, drift = 300, 40.0
    left, right = streams(n, jitter_ms=1.0, drift_ms=drift, seed=3)
    pairer = StereoPairer()
    pairs = feed(pairer, left, right)
    assert_consistent(pairer, pairs, left, right)
    used = {eye: {p[eye] for p in indices(pairs)} for eye in (0, 1)}
    skipped = {eye: sorted(set(range(max(used[eye]))) - used[eye]) for eye in (0, 1)}   # not the pending tail
    stats = pairer.stats()
    assert stats.skipped_left == len(skipped[0]) >= 1 and stats.skipped_right == len(skipped[1])
    assert stats.skipped_left - stats.skipped_right == 1    # the alignment moved by one frame
    offset = np.linspace(0.0, drift, n)
    for eye in (0, 1):
        assert all(12.0 < offset[i] < 21.5 for i in skipped[eye]), (eye, skipped[eye], offset[skipped[eye]])
    shifts = [li - ri for li, ri in indices(pairs)]
    assert shifts[:50] == [0] * 50 and shifts[-100:] == [1] * 100
    assert shifts == sorted(shifts)                            # no going back and forth


def test_jitter_drift_and_drops_together_keep_every_pair_within_15_ms():
    left, right = streams(600, jitter_ms=6.0, drift_ms=70.0, drop_left=0.03, seed=4)
    pairer = StereoPairer()
    pairs = feed(pairer, left, right)
    assert_consistent(pairer, pairs, left, right)
    stats = pairer.stats()
    assert stats.skipped > 600 - len(left) and len(pairs) > 400
    assert stats.max_abs_ms <= 15.0


def test_a_skew_over_15_ms_resyncs_below_10_ms():
    """L80/R68 is within 15 ms, but the pairer is resyncing after L40/R58 (18 ms) and R80 does better."""
    left, right = [0, 40, 80, 120, 160], [0, 58, 68, 80, 120, 160]
    to_ns = lambda ms: [(round(t * 1e6), i) for i, t in enumerate(ms)]   # noqa: E731
    pairer = StereoPairer()
    pairs = feed(pairer, to_ns(left), to_ns(right))
    assert times_ms(pairs) == [(0, 0), (80, 80), (120, 120), (160, 160)]
    assert (pairer.stats().skipped_left, pairer.stats().skipped_right) == (1, 2)
    without_hysteresis = StereoPairer(resync_skew_ms=15.0)
    pairs = feed(without_hysteresis, to_ns(left), to_ns(right))
    assert times_ms(pairs) == [(0, 0), (80, 68), (120, 120), (160, 160)]


def test_skipping_stops_when_it_stops_improving():
    """The right eye falls 20 ms behind from frame 3 on: one left frame is skipped, then the pairs
    hold at -13.3 ms, because skipping another right frame would make it 20 ms again."""
    n = 10
    t_left = [round(i * PERIOD_MS * 1e6) for i in range(n)]
    t_right = [round((i * PERIOD_MS + (20.0 if i >= 3 else 0.0)) * 1e6) for i in range(n)]
    pairer = StereoPairer()
    pairs = feed(pairer, list(zip(t_left, range(n))), list(zip(t_right, range(n))))
    assert indices(pairs) == [(0, 0), (1, 1), (2, 2)] + [(i + 1, i) for i in range(3, n - 1)]
    assert all(p.skew_ms == pytest.approx(20.0 - PERIOD_MS, abs=1e-5) for p in pairs[3:])
    assert (pairer.stats().skipped_left, pairer.stats().skipped_right) == (1, 0)


def test_while_resyncing_the_pairer_waits_for_the_behind_eye_next_frame():
    pairer = StereoPairer()
    for i, t in enumerate([0, 40, 80, 120]):
        pairer.push_left(round(t * 1e6), payload(i, 0))
    assert len(pairer.push_right(0, payload(0, 1))) == 1
    assert pairer.push_right(58_000_000, payload(1, 1)) == []        # 18 ms: skip L40, then R58 is behind
    assert pairer.push_right(68_000_000, payload(2, 1)) == []        # 12 ms, resyncing: would R3 do better?
    assert pairer.pending == (2, 1)
    (pair,) = pairer.push_right(80_000_000, payload(3, 1))           # yes: R68 skipped, L80 pairs with R80
    assert (pair.t_left_ns, pair.t_right_ns, ident(pair.right)) == (80_000_000, 80_000_000, 3)


def test_pairs_do_not_depend_on_arrival_order_or_threads():
    left, right = streams(400, jitter_ms=6.0, drift_ms=50.0, drop_left=0.02, drop_right=0.02, seed=5)
    reference = times_ms(feed(StereoPairer(), left, right))

    one_eye_first = StereoPairer(max_pending=1000)
    late = [one_eye_first.push_left(t, payload(i, 0)) for t, i in left]
    late += [one_eye_first.push_right(t, payload(i, 1)) for t, i in right]
    assert times_ms([p for batch in late for p in batch]) == reference

    threaded, results = StereoPairer(max_pending=1000), []

    def capture(push, frames, eye):
        for t, i in frames:
            results.extend(push(t, payload(i, eye)))

    threads = [threading.Thread(target=capture, args=(threaded.push_left, left, 0)),
               threading.Thread(target=capture, args=(threaded.push_right, right, 1))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert times_ms(sorted(results, key=lambda p: p.index)) == reference


def test_an_eye_without_partner_keeps_at_most_max_pending_frames():
    pairer = StereoPairer(max_pending=16)
    for i in range(20):
        assert pairer.push_left(round(i * PERIOD_MS * 1e6), payload(i, 0)) == []
    assert pairer.pending == (16, 0) and pairer.stats().skipped_left == 4
    (pair,) = pairer.push_right(round(4 * PERIOD_MS * 1e6) + 2_000_000, payload(0, 1))
    assert ident(pair.left) == 4 and pair.skew_ms == pytest.approx(2.0, abs=1e-5)


def test_statistics_before_any_pair_and_input_checks():
    pairer = StereoPairer()
    stats = pairer.stats()
    assert stats.pairs == 0 and stats.skipped == 0
    assert all(math.isnan(v) for v in (stats.mean_ms, stats.std_ms, stats.max_abs_ms))
    pairer.push_left(1_000, payload(0, 0))
    with pytest.raises(ValueError, match="left timestamps must not go backwards: 999 ns came after 1000 ns"):
        pairer.push_left(999, payload(1, 0))
    with pytest.raises(ValueError, match="right frame must be an HxWx3 uint8 BGR array"):
        pairer.push_right(1_000, np.zeros((1, 1)))
    with pytest.raises(ValueError, match="resync_skew_ms <= max_skew_ms"):
        StereoPairer(max_skew_ms=10.0, resync_skew_ms=12.0)
    with pytest.raises(ValueError, match="max_pending must be at least 2"):
        StereoPairer(max_pending=1)
