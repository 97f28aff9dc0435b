"""The frame reader that decodes ahead on a thread (trackers.data.sources.prefetch): same frames
in the same order, a reader's error raised after the frames before it, and no thread left behind
when the consumer stops early."""

import threading
import time

import pytest

from pfscope.trackers.data.sources import prefetch
from pfscope.trackers.errors import InputError


def _readers():
    return [t for t in threading.enumerate() if t.name == "pfscope-frame-reader"]


def _wait_gone(timeout=5.0):
    t0 = time.monotonic()
    while _readers() and time.monotonic() - t0 < timeout:
        time.sleep(0.02)
    return not _readers()


def test_same_items_in_the_same_order():
    def slow():
        for i in range(50):
            if i % 7 == 0:
                time.sleep(0.005)  # the reader falls behind now and then
            yield i
    assert list(prefetch(slow(), depth=3)) == list(range(50))
    assert _wait_gone()


def test_an_error_comes_after_the_frames_before_it():
    def broken():
        yield 1
        yield 2
        raise InputError("img1/000003.jpg: frame 3: truncated JPEG")
    got = []
    with pytest.raises(InputError, match="frame 3"):
        for x in prefetch(broken()):
            got.append(x)
    assert got == [1, 2]
    assert _wait_gone()


def test_stopping_early_ends_the_reader_and_closes_the_source():
    closed = threading.Event()

    def endless():
        try:
            i = 0
            while True:
                yield i
                i += 1
        finally:
            closed.set()
    stream = prefetch(endless(), depth=2)
    assert [next(stream) for _ in range(5)] == [0, 1, 2, 3, 4]
    stream.close()
    assert _wait_gone()
    assert closed.wait(5.0)


def test_a_run_on_real_frames_leaves_no_reader(tmp_path):
    """The pipeline closes the reader at the end of a run (and a run's tracks do not depend on
    the read-ahead: the recording tests compare same-seed recordings)."""
    import cv2
    import numpy as np

    from pfscope.trackers.data.sources import ImageFolderSource
    from pfscope.trackers.passthrough import PassThroughTracker
    from pfscope.trackers.pipeline import run

    for k in range(1, 9):
        cv2.imwrite(str(tmp_path / f"{k:06d}.png"), np.full((48, 64, 3), 10 * k, np.uint8))
    src = ImageFolderSource(tmp_path)
    seen = []

    class Spy(PassThroughTracker):
        needs_detections = False

        def step(self, frame, dets, level=None):
            seen.append((frame.index, int(frame.image[0, 0, 0])))
            return super().step(frame, dets, level)

    run(src, [Spy()], frames=5, score=False)
    assert seen == [(k, 10 * k) for k in range(1, 6)]
    assert _wait_gone()
