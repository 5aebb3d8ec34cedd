"""OdometryBuffer: what a frame's odometry is interpolated from when a driver delivers a backlog of SIPs at once."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from runtime.onboard import OdometryBuffer


def test_samples_stamped_alike_give_the_newest_pose_at_their_stamp():
    # A driver that fell behind reads three queued SIPs in one read and stamps them all with the read time: only
    # the last one was sent near that time, the first is two SIP cycles older.
    buffer = OdometryBuffer()
    buffer.add(1.0, np.array([0.0, 0.0, 0.0]))
    for heading in (0.1, 0.2, 0.3):
        buffer.add(1.3, np.array([0.0, 0.0, heading]))
    assert buffer.interpolate(1.3)[2] == 0.3
    np.testing.assert_allclose(buffer.interpolate(1.15), [0.0, 0.0, 0.15])
    buffer.add(1.2, np.array([9.0, 9.0, 9.0]))  # out of order: ignored
    assert buffer.latest_time == 1.3 and buffer.interpolate(1.3)[2] == 0.3


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 20), st.floats(-3.0, 3.0)), min_size=1, max_size=30))
def test_the_pose_at_a_stamp_is_the_last_one_added_with_it(samples):
    buffer = OdometryBuffer()
    last: dict[float, float] = {}
    for tick, heading in samples:
        t = 0.1 * tick
        if last and t < max(last):
            continue  # out of order: the buffer ignores it, so does the model
        buffer.add(t, np.array([0.0, 0.0, heading]))
        last[t] = heading
    for t, heading in last.items():
        assert buffer.interpolate(t)[2] == heading
