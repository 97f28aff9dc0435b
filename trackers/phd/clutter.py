"""Clutter learnt online: which kind of false detections the scene has (``clutter_model="learn"``;
not in maggio2007).

Real detectors make two kinds of false detections, and the filter needs a different κ(z) for
each:

- false detections that **repeat in place** (a pole, a shadow, a poster the detector fires on
  frame after frame, on and off): the §4 reading of the paper, one clutter point around each
  detection (``clutter_model="gate"``), keeps them from becoming tracks, but it also charges
  that clutter point to every real target, whose mass then settles near 0.8 (the filter
  under-counts by ~20 %);
- false detections **spread at random** over the image: a density over the whole image
  (``"scene"``, :class:`~.filter.SceneModel`) lets the mass follow the true count, but gives a
  place that fires again and again the same small κ as anywhere else, so it becomes a track.

The learnt model is their mixture, ``κ(z) = κ_u(z) + κ_r(z)``:

- ``κ_u`` is the ``scene`` density (uniform over the image, log-normal over the box size, rate
  λ_u estimated online, plus ``near_rate`` around each detection when set);
- ``κ_r`` is the ``gate`` model **only where clutter fell before**: a memory of the recent
  detections no target explained, each weighing its clutter share ``1 − won`` and fading with
  factor δ per frame, and ``κ_r(z) = β (1 − δ) S(z) / V(z)`` with ``S(z)`` the faded clutter
  weight inside the ``clutter_gate`` ellipsoid of z and ``V(z)`` that ellipsoid's volume (the
  ``gate`` model's: a detection at a place that fired on every recent frame gets ``β`` clutter
  points around it, as ``gate`` gives 1 to all).  A real target's detections are explained
  (``won ≈ 1``), so they leave no memory and keep the density's small κ: its mass follows the
  count.

β, the share of clutter that comes back in place, and λ_u are estimated together by EM, as the
``scene`` rate is: after each update, detection z's clutter share ``1 − won(z)`` is split between
the two kinds in proportion to ``κ_u(z)`` and ``κ_r(z)``; λ_u is the average of the random
shares per frame, β the average of the repeated shares over the average exposure ``(1 − δ) Σ
memory``.  On uniform clutter a false detection seldom falls inside an earlier one's gate (in
four dimensions: place and size), so β falls towards its floor and the model becomes the
``scene`` density; where the detector fires in place, β stays high and κ near those places is
the ``gate`` model's.  Nothing to set per scene: the prior is β = 1 (the ``gate`` model where
clutter was seen) and ``repeat_memory`` × ``clutter_memory`` frames of memory (the place
memory).  Deterministic (no randomness); memory bounded (faded entries are dropped).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from .gating import gate_pairs

if TYPE_CHECKING:  # pragma: no cover
    from .filter import ClutterParams, LikelihoodParams

#: β never goes below this (EM cannot revive a component at exactly zero)
BETA_FLOOR = 0.01
#: memory entries whose faded weight is below this are dropped
MIN_WEIGHT = 1e-3


class PlaceClutter:
    """The repeated-in-place part ``κ_r`` and the EM for β (module docstring).  One instance per
    filter; ``log_kappa`` then ``learn`` once per frame."""

    def __init__(self, cl: "ClutterParams", lk: "LikelihoodParams"):
        self.cl, self.lk = cl, lk
        self.beta = float(cl.repeat_prior)
        self.mem_z = np.zeros((0, 4))       # past detections (y1, y2, w, h)
        self.mem_w = np.zeros(0)            # their faded clutter share
        # EM sums (exponential averages): repeated share per frame, exposure per frame; the
        # prior is one clutter point of exposure at repeat_prior
        self.num = float(cl.repeat_prior)
        self.den = 1.0
        self.frames = 0

    @property
    def fade(self) -> float:
        """δ: the memory's decay per frame (1 − 1/frames of memory)."""
        frames = max(1.0, self.cl.repeat_memory * self.cl.clutter_memory)
        return 1.0 - 1.0 / frames if frames > 1 else 0.0

    def _weight_in_gates(self, Z: np.ndarray) -> np.ndarray:
        """``S(z)`` (N_z,): the memory's faded clutter weight inside each z's gate."""
        from .filter import OBS_DIM, gate_threshold, obs_std

        S = np.zeros(len(Z))
        if len(Z) and len(self.mem_w):
            r2 = gate_threshold(self.cl.clutter_gate, OBS_DIM)
            for ch in gate_pairs(self.mem_z, Z, r2, std_z=obs_std(Z[:, 2:4], self.lk)):
                S += np.bincount(ch.cols, weights=self.mem_w[ch.rows], minlength=len(Z))
        return S

    def log_kappa(self, Z: np.ndarray) -> np.ndarray:
        """``log κ_r(z)`` (N_z,) of this frame's detections (``-inf`` where no clutter fell)."""
        from .filter import log_clutter_density

        rate = self.beta * np.minimum(self._weight_in_gates(Z), 1.0)
        with np.errstate(divide="ignore"):
            per_point = log_clutter_density(Z, replace(self.cl, clutter_rate=1.0), self.lk)
            return np.log(rate) + per_point

    def log_gate(self, Z: np.ndarray, share: float) -> np.ndarray:
        """``log`` of the ``gate`` model at rate ``share`` around every detection: the part of
        κ that stands for structured clutter the memory has not placed yet."""
        from .filter import log_clutter_density

        return log_clutter_density(Z, replace(self.cl, clutter_rate=max(share, 0.0)), self.lk)

    def exposure(self) -> float:
        """Places where clutter fell, each counted once: Σ_j w_j / max(1, S(z_j))."""
        if not len(self.mem_w):
            return 0.0
        S = self._weight_in_gates(self.mem_z)
        return float(np.sum(self.mem_w / np.maximum(S, 1.0)))

    def learn(self, Z: np.ndarray, clutter_share: np.ndarray, repeat_share: np.ndarray,
              a: float) -> None:
        """After the update: ``clutter_share`` (N_z,) = 1 − won, ``repeat_share`` the part of it
        given to κ_r; ``a`` the averaging weight of this frame (as the scene rate's)."""
        exposure = self.exposure()
        self.num = (1 - a) * self.num + a * float(np.sum(repeat_share))
        self.den = (1 - a) * self.den + a * exposure
        if self.den > 0:
            self.beta = float(np.clip(self.num / self.den, BETA_FLOOR, 1.0))
        self.frames += 1
        # fade the memory, add this frame's clutter, drop what has faded away
        w = np.concatenate([self.mem_w * self.fade, np.asarray(clutter_share, dtype=float)])
        z = np.vstack([self.mem_z, np.asarray(Z, dtype=float).reshape(-1, 4)])
        keep = w >= MIN_WEIGHT
        self.mem_z, self.mem_w = z[keep], w[keep]


#: the "near people" neighbourhood: this many times the observation stds of the clutter gate
#: (the misplaced, partial and duplicate boxes a detector puts next to a person overlap it,
#: IoU ~0.2-0.5, mostly outside the 99 % gate of its own noise)
NEAR_SCALE = 2.0


class NearClutter:
    """False detections that come with the people (``κ_n``; module docstring): ``ν`` clutter
    points per target, spread as the ``gate`` model around the detection, where the predicted
    targets are: ``κ_n(z) = ν min(1, M'(z)) / V(z)`` with ``M'(z)`` the predicted mass inside
    ``NEAR_SCALE`` × the clutter gate of z.  ν by EM: the detections' near shares over the
    predicted mass (each target makes ν of them a frame on average)."""

    def __init__(self, cl: "ClutterParams", lk: "LikelihoodParams"):
        self.cl, self.lk = cl, lk
        self.nu = float(cl.repeat_prior)
        self.num = float(cl.repeat_prior)
        self.den = 1.0
        self._exposure = 0.0

    def log_kappa(self, Z: np.ndarray, predicted) -> np.ndarray:
        from .filter import BirthParams, log_clutter_density, mass_near

        self._exposure = float(predicted.mass) if predicted is not None else 0.0
        if predicted is None or not len(Z):
            return np.full(len(Z), -np.inf)
        wide = replace(self.lk, sigma_obs=self.lk.sigma_obs * NEAR_SCALE,
                       sigma_obs_min=self.lk.sigma_obs_min * NEAR_SCALE)
        m = mass_near(predicted, Z, BirthParams(gate=self.cl.clutter_gate), wide)
        with np.errstate(divide="ignore"):
            per_point = log_clutter_density(Z, replace(self.cl, clutter_rate=1.0), self.lk)
            return np.log(self.nu * np.minimum(m, 1.0)) + per_point

    def learn(self, near_share: np.ndarray, a: float) -> None:
        self.num = (1 - a) * self.num + a * float(np.sum(near_share))
        self.den = (1 - a) * self.den + a * self._exposure
        if self.den > 0:
            self.nu = float(np.clip(self.num / self.den, BETA_FLOOR, 1.0))


def clutter_share(won: np.ndarray, log_used: np.ndarray, log_shadow: np.ndarray) -> np.ndarray:
    """Each detection's clutter share under the shadow model, ``κ_s / (κ_s + C)``, from ``won =
    C / (κ_used + C)`` of the update (which ran with κ_used)."""
    won = np.clip(np.asarray(won, dtype=np.float64), 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_c = np.log(won) - np.log1p(-won) + log_used        # log C(z)
        out = 1.0 / (1.0 + np.exp(log_c - log_shadow))
    return np.where(np.isfinite(out), out, np.where(won >= 1.0, 0.0, 1.0))
