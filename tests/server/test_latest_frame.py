"""The streamed transports' one-slot mailbox: the newest cloud wins, a replaced one counts as dropped, and close()
stops the stream thread without handing it a stale frame."""

from __future__ import annotations

import threading
import time

from graspd.server.services.ros_stream import LatestFrame


def test_a_newer_frame_replaces_one_not_taken_and_says_so() -> None:
    frames = LatestFrame()
    assert frames.put(b"a", "pointcloud2") is False
    assert frames.put(b"b", "cloud_sources") is True  # "a" was never taken: dropped
    assert frames.take() == (b"b", "cloud_sources")
    assert frames.put(b"c", "pointcloud2") is False


def test_take_waits_for_a_frame_and_close_wakes_it_with_none() -> None:
    frames = LatestFrame()
    got: list[tuple[bytes, str] | None] = []
    thread = threading.Thread(target=lambda: got.extend([frames.take(), frames.take()]))
    thread.start()
    time.sleep(0.05)
    assert got == []  # waiting, not spinning out with nothing
    frames.put(b"x", "pointcloud2")
    time.sleep(0.05)
    frames.put(b"stale", "pointcloud2")
    frames.close()
    thread.join(timeout=2)
    assert not thread.is_alive()
    assert got[0] == (b"x", "pointcloud2")
    assert got[1] in (None, (b"stale", "pointcloud2"))  # the second take raced the close
    assert frames.take() is None
