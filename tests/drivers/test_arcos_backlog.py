"""SIPs that queued while the driver's reader was not reading (a starved process) are read in one go and stamped
with that read's time, over TCP too (pyserial's socket:// reports 0 or 1 bytes waiting): a byte-at-a-time reader
that fell behind stamped each backlogged SIP as it caught up, seconds after it was sent, and the runtime gave
frames the odometry of another instant (runtime.onboard.OdometryBuffer keeps the newest of a shared stamp)."""
from __future__ import annotations

import threading

import pytest

from drivers.arcos.robot import P3AT

FAILURE_BOUND = 30.0  # a failure bound only (see test_arcos_driver.py)


@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_sips_waiting_together_are_read_in_one_go_with_one_stamp(transport, tcp_peer, fake_peer_factory):
    peer = tcp_peer if transport == "tcp" else fake_peer_factory()
    burst: list[tuple[float, float]] = []
    done = threading.Event()

    def on_state(state) -> None:
        if state.x >= 0.999:
            burst.append((state.stamp, state.x))
            if len(burst) == 8:
                done.set()

    with P3AT(peer.url) as robot:
        robot.wait_for_state(FAILURE_BOUND)
        robot.subscribe(on_state)
        peer.send_burst(8, x0=1.0)
        assert done.wait(FAILURE_BOUND)
    burst = burst[:8]  # the peer's stream goes on after the burst (at its last x)
    xs = [x for _, x in burst]
    assert xs == pytest.approx([1.0 + 0.001 * k for k in range(8)], abs=1e-9)
    assert len({stamp for stamp, _ in burst}) == 1, "the burst's SIPs were stamped at different reads"
