"""Checked by mypy in tests/test_typecheck.py (not run): every built-in tracker satisfies the
Tracker protocol, and the pipeline's and reporters' contracts are used as declared.  A change
that makes a tracker drift from the protocol fails CI here."""

from __future__ import annotations

import numpy as np

from pfscope.trackers.api import StepResult, Tracker
from pfscope.trackers.passthrough import PassThroughTracker
from pfscope.trackers.phd.filter import GaussianLikelihood, Likelihood
from pfscope.trackers.phd.tracker import MTTracker, PHDTracker
from pfscope.trackers.pipeline import BaseHook, Hook, TracksFileHook
from pfscope.trackers.types import Detections, Frame

rng = np.random.default_rng(0)
trackers: list[Tracker] = [PHDTracker(rng=rng), MTTracker(rng=rng), PassThroughTracker(rng=rng)]
hooks: list[Hook] = [BaseHook(), TracksFileHook("/dev/null")]
likelihood: Likelihood = GaussianLikelihood()


def step_all(frame: Frame, dets: Detections) -> list[StepResult]:
    return [t.step(frame, dets, "particles") for t in trackers]
