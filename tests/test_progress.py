"""The progress line shows the recent frame rate (issue 22), on a fake clock."""

import io

from pfscope.viewer_app.run import Progress


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _run(bar, clock, durations):
    done = 0
    for d in durations:
        clock.t += d
        done += 1
        bar.update(done)
    return done


def test_rate_is_recent_not_cumulative():
    clock = FakeClock()
    out = io.StringIO()
    bar = Progress(300, "t", stream=out, clock=clock, window=2.0)
    clock.t = 100.0
    bar.start()
    # a 30-second first frame (a compile, a cold disk), then 50 frames a second
    _run(bar, clock, [30.0] + [0.02] * 200)
    assert abs(bar.rate() - 50.0) < 1.0          # cumulative would be 201 / 34 s ≈ 5.9 fps
    assert abs(bar.eta(201) - 99 / 50.0) < 0.1   # the ETA follows the recent rate
    # the machine slows to 10 frames a second: the rate follows within the window
    _run(bar, clock, [0.1] * 40)
    assert abs(bar.rate() - 10.0) < 0.5


def test_clock_starts_at_start_not_at_construction():
    clock = FakeClock()
    out = io.StringIO()
    bar = Progress(10, "t", stream=out, clock=clock)
    clock.t = 60.0                                # set-up before the frames (kernels, files)
    bar.start()
    clock.t += 0.5
    bar.update(1)
    assert abs(bar.rate() - 2.0) < 1e-9           # 1 frame in 0.5 s, not in 60.5 s


def test_lines_show_the_recent_rate():
    clock = FakeClock()
    out = io.StringIO()                           # not a terminal: a line every 10 %
    bar = Progress(100, "lane", stream=out, clock=clock)
    bar.start()
    _run(bar, clock, [20.0] + [0.04] * 99)
    last = out.getvalue().strip().splitlines()[-1]
    assert last == "lane: 100/100 frames, 25.0 fps"


def test_rate_zero_before_frames():
    bar = Progress(10, "t", stream=io.StringIO(), clock=FakeClock())
    bar.start()
    assert bar.rate() == 0.0 and bar.eta(0) is None
