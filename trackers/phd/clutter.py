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
  factor δ per frame, and ``κ_r(z) = r(z) / V(z)`` with ``V(z)`` the ``clutter_gate``
  ellipsoid's volume and ``r(z)`` the clutter rate per frame of z's place: the posterior mean
  ``(S + n0 β) / (E + n0)`` of a Poisson rate under a Gamma prior of mean β and ``n0 =
  PRIOR_FRAMES`` frames, ``S(z)`` the faded clutter weight inside z's gate and ``E(z)`` the
  faded number of frames the place has been remembered.  A spot that fires on every frame
  climbs towards ``r = 1`` (the ``gate`` model there); a place where clutter fell once sinks to
  ``~β`` and below as it stays quiet.  A real target's detections are explained (``won ≈ 1``),
  so they leave no memory and keep the density's small κ: its mass follows the count;
- ``κ_n`` (:class:`NearClutter`) is ν false boxes per predicted target around it (duplicate,
  misplaced and partial boxes next to a person), none for a detection that continues a chain
  of mutually nearest detections (:class:`~.scene_motion.Chains`): such a detection is a
  person's or a spot's, a box beside a person does not chain.

β, the share of clutter that comes back in place, ν and λ_u are estimated together by EM, as
the ``scene`` rate is: after each update, detection z's clutter share ``1 − won(z)`` is split
between the kinds in proportion to ``κ_u(z)``, ``κ_r(z)`` and ``κ_n(z)``; λ_u is the average of
the random shares per frame, β the average of the repeated shares over the average exposure
(the places in memory, each counted once), ν the near shares over the predicted mass.  β and ν
carry a Gamma prior (:func:`em_rate`, ``PRIOR_FRAMES`` frames of evidence at the prior mean,
held, not faded): where their exposure is ~0 (no place remembered; no target formed yet, so
that each detection of a person would read as clutter next to the little mass the previous one
left) they stay at the prior instead of running to their clip.

Which κ the update uses is ``learn_update``: ``'gate'`` the random density plus the ``gate``
model at the learnt share of structured clutter around every detection (a stand-in for the
structured clutter the memory has not placed yet; safe where a detector puts duplicate boxes
next to people, PETS09's ACF, but as strict as ``gate`` where the structured share is high);
``'model'`` the learnt mixture ``κ_u + κ_r + κ_n + κ_d`` itself, ``κ_d``
(:class:`DuplicateBoxes`) the second boxes a detector puts on a person it already boxed, which
a Poisson clutter term cannot express.  On uniform clutter a false detection seldom falls inside an earlier one's gate (in
four dimensions: place and size), so β falls towards its floor and the model becomes the
``scene`` density; where the detector fires in place, β stays high and κ near those places is
the ``gate`` model's.  Nothing to set per scene: the prior is β = 1 (the ``gate`` model where
clutter was seen) and ``repeat_memory`` × ``clutter_memory`` frames of memory (the place
memory).  Deterministic (no randomness); memory bounded (faded entries are dropped).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Optional

import numpy as np
from numba import njit

from . import _kernels
from .camera_motion import _pairwise
from .gating import BRUTE_PAIRS, _gate_sums, _gate_sums_cells, gate_sums

if TYPE_CHECKING:  # pragma: no cover
    from .filter import ClutterParams, LikelihoodParams

#: β never goes below this (EM cannot revive a component at exactly zero)
BETA_FLOOR = 0.01
#: strength of the prior of each EM rate (β, ν), in frames of evidence at the prior mean: the
#: rate is ``(Σ counts + n0 · prior) / (Σ exposure + n0)`` over the memory (a Gamma prior, the
#: conjugate of a Poisson rate, held constant instead of fading like the evidence).  With no
#: exposure (no clutter place remembered, no predicted target) the rate stays at its prior
#: instead of running to a clip; ``n0`` frames of one place / one target outweigh it half.
PRIOR_FRAMES = 5.0
#: prior mean of ν (false detections next to each target per frame): none until the
#: detections show them
NEAR_PRIOR = BETA_FLOOR


def em_rate(num: float, den: float, prior: float, a: float) -> float:
    """The EM rate with its conjugate prior (:data:`PRIOR_FRAMES`): ``num`` / ``den`` are the
    exponential averages of the counts / the exposure per frame, ``a`` the weight of the last
    frame in them (1 / memory once the memory is full), ``prior`` the prior mean.  Clipped to
    [BETA_FLOOR, 1]."""
    n0 = PRIOR_FRAMES * a
    # np.clip's float without its array machinery (three calls a frame; NaN stays NaN)
    return float(min(max((num + n0 * prior) / (den + n0), BETA_FLOOR), 1.0))
#: memory entries whose faded weight is below this are dropped
MIN_WEIGHT = 1e-3


class PlaceClutter:
    """The repeated-in-place part ``κ_r`` and the EM for β (module docstring).  β (learnt)
    models the mean clutter rate per frame of a place where clutter fell: the prior mean of
    each place's own rate :meth:`place_rate`.  One instance per filter; ``log_kappa`` then
    ``learn`` once per frame."""

    def __init__(self, cl: "ClutterParams", lk: "LikelihoodParams"):
        self.cl, self.lk = cl, lk
        self.beta = float(cl.repeat_prior)
        self.mem_z = np.zeros((0, 4))       # past detections (y1, y2, w, h)
        self.mem_w = np.zeros(0)            # their faded clutter share
        self.mem_e = np.zeros(0)            # the faded frames each has been remembered
        # the memory's observation stds and S(z) of each entry (its faded clutter weight
        # inside its gate), kept along the memory; for the likelihood / gate r² in _sums_of
        self.mem_s = np.zeros((0, 4))
        self._sums: Optional[tuple] = None  # (lk, r², S, exposure) or None: compute again
        # EM sums (exponential averages): repeated share per frame, exposure per frame; the
        # prior is one clutter point of exposure at repeat_prior
        self.num = 0.0
        self.den = 0.0
        self._a = 0.2                       # the weight of one frame in num / den (SceneModel)
        self.frames = 0

    def count(self) -> float:
        """Clutter repeated in place per frame, the prior's pseudo-counts included."""
        return self.num + PRIOR_FRAMES * self._a * self.cl.repeat_prior

    @property
    def fade(self) -> float:
        """δ: the memory's decay per frame (1 − 1/frames of memory)."""
        frames = max(1.0, self.cl.repeat_memory * self.cl.clutter_memory)
        return 1.0 - 1.0 / frames if frames > 1 else 0.0

    def _weight_in_gates(self, Z: np.ndarray, watched: bool = False,
                         std: Optional[np.ndarray] = None):
        """``S(z)`` (N_z,): the memory's faded clutter weight inside each z's gate; with
        ``watched`` also ``E(z)``, the faded frames the oldest of them has been remembered.
        ``std``: ``obs_std(Z[:, 2:4], lk)`` when the caller has it."""
        F = _filter
        if len(Z) and len(self.mem_w):
            S, E, _ = gate_sums(self.mem_z, Z, F.gate_threshold(self.cl.clutter_gate, F.OBS_DIM),
                                F.obs_std(Z[:, 2:4], self.lk) if std is None else std,
                                self.mem_w, self.mem_e)
        else:
            S = np.zeros(len(Z))
            E = np.zeros(len(Z))
        return (S, E) if watched else S

    def place_rate(self, Z: np.ndarray, std: Optional[np.ndarray] = None) -> np.ndarray:
        """Each detection's place's clutter rate per frame (N_z,; 0 where no clutter fell): the
        posterior mean of a Poisson rate with the Gamma prior of mean β and ``PRIOR_FRAMES``
        frames, ``(S + n0 β) / (E + n0)``, from the clutter seen there (S, faded) over the
        frames the place has been watched (E, faded alike).  A spot that fires on every frame
        climbs towards 1 (the ``gate`` model there; E/(E + n0) of it, E at most the memory's
        1/(1 − δ) frames); a place where clutter fell once sinks towards β·n0/(E + n0) as it
        stays quiet.  ``std``: the detections' observation stds when the caller has them."""
        S, E = self._weight_in_gates(Z, watched=True, std=std)
        r = (S + PRIOR_FRAMES * self.beta) / (E + PRIOR_FRAMES)
        return np.where(S > 0, np.minimum(r, 1.0), 0.0)

    def log_kappa(self, Z: np.ndarray, log_v: Optional[np.ndarray] = None,
                  std: Optional[np.ndarray] = None) -> np.ndarray:
        """``log κ_r(z)`` (N_z,) of this frame's detections (``-inf`` where no clutter fell).
        ``log_v``, ``std``: the clutter gates' ``log V(z)`` and the detections' observation
        stds (:func:`.filter.obs_std`) when the caller has them."""
        S, E = self._weight_in_gates(Z, watched=True, std=std)
        return kappa_terms(_log_v(Z, self.cl, self.lk, log_v), place=(S, E, self.beta))[0]

    def log_gate(self, Z: np.ndarray, share: float,
                 log_v: Optional[np.ndarray] = None) -> np.ndarray:
        """``log`` of the ``gate`` model at rate ``share`` around every detection: the part of
        κ that stands for structured clutter the memory has not placed yet."""
        from .filter import log_clutter_density

        if log_v is None or not share > 0:
            return log_clutter_density(Z, replace(self.cl, clutter_rate=max(share, 0.0)),
                                       self.lk)
        return math.log(share) - log_v

    def _sums_of(self, r2: Optional[float] = None) -> tuple:
        """``(lk, r², S, exposure)`` of the memory as it is: each entry's ``S`` and
        :meth:`exposure`, kept along the memory by :meth:`learn` (:func:`_memory_step`),
        computed again (one grid pass, :func:`.gating.gate_sums`) when missing or when the
        likelihood (the memory's stds) or the gate changed.  ``r2``: the clutter gate's r²
        when the caller has it."""
        F = _filter
        if r2 is None:
            r2 = F.gate_threshold(self.cl.clutter_gate, F.OBS_DIM)
        sums = self._sums
        if sums is None or sums[0] is not self.lk or sums[1] != r2:
            if sums is None or sums[0] is not self.lk or len(self.mem_s) != len(self.mem_z):
                self.mem_s = F.obs_std(self.mem_z[:, 2:4], self.lk)
            S = gate_sums(self.mem_z, self.mem_z, r2, self.mem_s, self.mem_w)[0] \
                if len(self.mem_w) else np.zeros(0)
            sums = self._sums = (self.lk, r2, S, _exposure_sum(self.mem_w, S))
        return sums

    def exposure(self) -> float:
        """Places where clutter fell, each counted once: Σ_j w_j / max(1, S(z_j))."""
        return self._sums_of()[3] if len(self.mem_w) else 0.0

    def learn(self, Z: np.ndarray, clutter_share: np.ndarray, repeat_share: np.ndarray,
              a: float, std: Optional[np.ndarray] = None,
              repeat_sum: Optional[float] = None) -> None:
        """After the update: ``clutter_share`` (N_z,) = 1 − won, ``repeat_share`` the part of it
        given to κ_r; ``a`` the averaging weight of this frame (as the scene rate's); ``std``:
        the detections' observation stds when the caller has them; ``repeat_sum``:
        ``np.sum(repeat_share)`` when the caller has it (:func:`learn_shares`)."""
        lk, r2, S, exposure = self._sums_of()     # (an empty memory's exposure is 0)
        if repeat_sum is None:
            repeat_sum = float(np.sum(repeat_share))
        self.em_step(a, repeat_sum, exposure)
        Z = np.ascontiguousarray(np.asarray(Z, dtype=np.float64).reshape(-1, 4))
        if std is None:
            std = _filter.obs_std(Z[:, 2:4], self.lk)
        # fade the memory, add this frame's clutter, drop what has faded away, and S and the
        # exposure of the memory after it (one pass)
        self.keep_memory(lk, r2, _memory_step(
            self.mem_z, self.mem_s, self.mem_w, self.mem_e, S, Z,
            np.ascontiguousarray(std, dtype=np.float64),
            np.ascontiguousarray(clutter_share, dtype=np.float64), self.fade, MIN_WEIGHT,
            float(r2), INCREMENT_PAIRS))

    def em_step(self, a: float, repeat_sum: float, exposure: float) -> None:
        """The EM average of the repeat rate β from this frame's repeat share ``repeat_sum``
        and the memory's ``exposure`` before it (:meth:`learn`, and the fused
        :meth:`.filter.SceneModel.learn`)."""
        self.num = (1 - a) * self.num + a * repeat_sum
        self.den = (1 - a) * self.den + a * exposure
        self.beta = em_rate(self.num, self.den, self.cl.repeat_prior, a)
        self._a = a
        self.frames += 1

    def keep_memory(self, lk, r2: float, step: tuple) -> None:
        """The memory after :func:`_memory_step` (its returned ``step``: entries, S, exposure,
        whether S is valid)."""
        self.mem_z, self.mem_s, self.mem_w, self.mem_e, S, exposure, ok = step
        self._sums = (lk, r2, S, exposure) if ok else None


#: the place memory's S(z) after a frame is its S faded, minus the dropped entries, plus the
#: new ones (one brute pass over those pairs) up to this many pairs; above, one grid pass over
#: the whole memory the next frame (linear in the memory)
INCREMENT_PAIRS = 65536


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _exposure_sum(w, S):
    """``Σ_j w_j / max(1, S_j)`` (numpy's pairwise order)."""
    n = np.int64(w.shape[0])
    t = np.empty(n)
    for j in range(n):
        t[j] = w[j] / (S[j] if S[j] > 1.0 else 1.0)
    return _pairwise(t, n)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _memory_step(mem_z, mem_s, mem_w, mem_e, mem_S, Z, Z_s, share, fade, min_w, r2, budget):
    """The place memory after a frame: the old entries' weights and exposures faded (``w δ``,
    ``e δ + 1``), this frame's detections appended (weight ``share``, exposure 1, stds
    ``Z_s``), those below ``min_w`` dropped -- the same floats as the numpy concatenation and
    mask; then each entry's ``S`` (the faded weight inside its gate ``d² <= r2``, itself
    included): an old entry's ``S δ``, minus the dropped entries inside its gate, plus the new
    ones, a new entry's by a pass over the memory; and the exposure (:func:`_exposure_sum`).
    Returns ``(z, s, w, e, S, exposure, ok)``; ``ok`` False (S, exposure not computed) when
    that takes more than ``budget`` pairs."""
    n_old, n_new = mem_w.shape[0], share.shape[0]
    k_old = np.int64(0)
    k_new = np.int64(0)
    for i in range(n_old):
        k_old += mem_w[i] * fade >= min_w
    for i in range(n_new):
        k_new += share[i] >= min_w
    keep = k_old + k_new
    z = np.empty((keep, 4))
    s = np.empty((keep, 4))
    w = np.empty(keep)
    e = np.empty(keep)
    src = np.empty(keep, np.int64)          # an old entry's index, or -1 - a new one's
    k = 0
    for i in range(n_old):
        wi = mem_w[i] * fade
        if wi >= min_w:
            for c in range(4):
                z[k, c], s[k, c] = mem_z[i, c], mem_s[i, c]
            w[k] = wi
            e[k] = mem_e[i] * fade + 1.0
            src[k] = i
            k += 1
    for i in range(n_new):
        if share[i] >= min_w:
            for c in range(4):
                z[k, c], s[k, c] = Z[i, c], Z_s[i, c]
            w[k] = share[i]
            e[k] = 1.0
            src[k] = -1 - i
            k += 1
    S = np.empty(keep)
    dropped = n_old - k_old
    ok = mem_S.shape[0] == n_old and (dropped + k_new) * k_old + k_new * keep <= budget
    if not ok:
        return z, s, w, e, S, 0.0, False
    R = np.sqrt(r2) * (1.0 + GATE_MARGIN)
    drop = np.empty(dropped, np.int64)      # the dropped entries, once (in index order)
    d = 0
    for q in range(n_old):
        if not mem_w[q] * fade >= min_w:
            drop[d] = q
            d += 1
    for k in range(k_old):
        i = src[k]
        acc = mem_S[i] * fade
        for t in range(dropped):
            q = drop[t]
            if _in_gate_early(mem_z, q, mem_z, i, mem_s, r2, R):
                acc -= mem_w[q] * fade
        for q in range(k_old, keep):
            if _in_gate_early(z, q, z, k, s, r2, R):
                acc += w[q]
        S[k] = acc
    for k in range(k_old, keep):
        acc = 0.0
        for q in range(keep):
            if _in_gate_early(z, q, z, k, s, r2, R):
                acc += w[q]
        S[k] = acc
    return z, s, w, e, S, _exposure_sum(w, S), True


#: the "near people" neighbourhood: this many times the observation stds of the clutter gate
#: (the misplaced, partial and duplicate boxes a detector puts next to a person overlap it,
#: IoU ~0.2-0.5, mostly outside the 99 % gate of its own noise)
NEAR_SCALE = 2.0


class NearClutter:
    """False detections that come with the people (``κ_n``; module docstring): ``ν`` clutter
    points per target, spread as the ``gate`` model around the detection, where the predicted
    targets are: ``κ_n(z) = ν min(1, M'(z)) / V(z)`` with ``M'(z)`` the predicted mass inside
    ``NEAR_SCALE`` × the clutter gate of z.  ν (learnt) models the mean number of false boxes
    a target brings next to it per frame; by EM, the detections' near shares over the predicted
    mass, with the Gamma prior of :func:`em_rate` (mean ``NEAR_PRIOR``: none until the
    detections show them), so that ν cannot run to its clip while the predicted mass is ~0.
    A detection that continues a chain gets no κ_n (its near share is 0: module docstring)."""

    def __init__(self, cl: "ClutterParams", lk: "LikelihoodParams"):
        self.cl, self.lk = cl, lk
        self.nu = NEAR_PRIOR
        self.num = 0.0
        self.den = 0.0
        self._a = 0.2
        self._exposure = 0.0
        self._gate: Optional[tuple] = None      # (lk, cl, widened lk, gate) of log_kappa

    def _wide(self) -> tuple:
        """(the likelihood widened by :data:`NEAR_SCALE`, the birth gate at the clutter gate),
        built again only when the settings change."""
        from .filter import BirthParams

        if self._gate is None or self._gate[0] is not self.lk or self._gate[1] is not self.cl:
            self._gate = (self.lk, self.cl, _widened(self.lk, NEAR_SCALE),
                          BirthParams(gate=self.cl.clutter_gate))
        return self._gate[2:]

    def wide_std_of(self, std: np.ndarray) -> np.ndarray:
        """The detections' observation stds ``std`` times :data:`NEAR_SCALE` (N_z, 4): the gates
        of κ_n's mass and of :class:`DuplicateBoxes`.  The same floats as :func:`.filter.obs_std`
        of the likelihood widened by NEAR_SCALE (a power of two: σ scaled by it is exact, and
        so is every product and max of obs_std after it), one multiply instead of obs_std."""
        return std * NEAR_SCALE

    def log_kappa(self, Z: np.ndarray, predicted, log_v: Optional[np.ndarray] = None,
                  chained: Optional[np.ndarray] = None,
                  std: Optional[np.ndarray] = None) -> np.ndarray:
        """``log κ_n(z)`` (N_z,); ``-inf`` where ``chained`` (those continue a chain: no κ_n,
        module docstring), whose predicted mass is then not summed.  ``std``: :meth:`wide_std_of`
        of ``Z``'s stds when the caller has it."""
        m = self.mass(Z, predicted, chained, std)
        if m is None:
            return np.full(len(Z), -np.inf)
        return kappa_terms(_log_v(Z, self.cl, self.lk, log_v), near=(m, self.nu, chained))[1]

    def mass(self, Z: np.ndarray, predicted, chained: Optional[np.ndarray] = None,
             std: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
        """``M'(z)`` (N_z,) of :meth:`log_kappa` (0 where ``chained``), None without
        predicted particles or detections; records the predicted mass for :meth:`learn`."""
        from .filter import mass_near

        self.record(predicted)
        if predicted is None or not len(Z):
            return None
        wide, bp = self._wide()
        return mass_near(predicted, Z, bp, wide, std_z=std, skip=chained)

    def record(self, predicted, exposure: Optional[float] = None) -> None:
        """Records the predicted mass of this frame for :meth:`learn` (:meth:`mass` does);
        ``exposure``: that mass when the caller made it already (the same float)."""
        if exposure is not None:
            self._exposure = exposure
            return
        if predicted is None:
            self._exposure = 0.0
            return
        if not predicted.made("mass", "log_mass") and predicted.is_known_equal():
            lw = predicted.log_weights
            lw0 = float(lw[0])
            if math.isfinite(lw0):
                # ParticleSet.mass of equal weights without its cached properties: the same
                # numpy calls (log n of a 1-element array, np.exp of the float), log n kept
                self._exposure = float(np.exp(_log_count(len(lw)) + lw0))
                return
        self._exposure = float(predicted.mass)

    def learn(self, near_share: Optional[np.ndarray], a: float,
              near_sum: Optional[float] = None) -> None:
        """After the update: ``near_share`` (N_z,) the clutter share the EM gives to κ_n (none
        for a detection that continues a chain: :meth:`.filter.SceneModel.learn`);
        ``near_sum``: ``np.sum(near_share)`` when the caller has it (:func:`learn_shares`;
        ``near_share`` is not read then, and may be None)."""
        if near_sum is None:
            near_sum = float(np.sum(near_share))
        self.num = (1 - a) * self.num + a * near_sum
        self.den = (1 - a) * self.den + a * self._exposure
        self.nu = em_rate(self.num, self.den, NEAR_PRIOR, a)
        self._a = a

    def count(self) -> float:
        """Near-people clutter per frame, the prior's pseudo-counts included."""
        return self.num + PRIOR_FRAMES * self._a * NEAR_PRIOR


_LOG_COUNTS: dict = {}


def _log_count(n: int) -> float:
    """``np.log(np.array([float(n)]))[0]`` (numpy's log: :attr:`.smc.weights.ParticleSet.
    log_mass`' float of equal weights), kept for each n seen."""
    v = _LOG_COUNTS.get(n)
    if v is None:
        if len(_LOG_COUNTS) > 4096:
            _LOG_COUNTS.clear()
        v = _LOG_COUNTS[n] = float(np.log(np.array([float(n)]))[0])
    return v


class DuplicateBoxes:
    """Second boxes on a person the detector already boxed (``κ_d``, ``learn_update='model'``).

    What it models: a detector (PETS09's ACF) often puts a second box on a person it boxed,
    shifted or resized, inside ``NEAR_SCALE`` × the clutter gate of the first.  A Poisson
    clutter term cannot express that: the PHD reads the second box as a second person.  The
    persons' boxes are not known at update time, so each detection stands in for one (as the
    births do): a box z with ``n(z)`` other detections of the frame in its widened gate
    (:func:`neighbour_pairs`) is the second box of one of them with probability ``q``, spread
    as the ``gate`` model: ``κ_d(z) = q · n(z) / V(z)`` (``V(z)`` the clutter gate's volume).
    Both boxes of a pair get it (either may be the second one); a box alone gets none.  A
    person already tracked keeps its box (its predicted ``C(z) ≫ q / V(z)``); a box next to it
    that the prediction does not explain stays clutter instead of starting a second track.
    Linear in detections (grid-indexed pairs; no particles × detections).

    ``q`` (learnt) is the probability that the other box next to a tracked person's box is a
    second box on that person rather than another person: over the detections z with a
    neighbour, ``Σ_z won(z) · [some z' near z has won(z') < ½]`` over ``Σ_z won(z)`` (``won``
    the update's target share; a neighbour counts as unexplained where the update found
    clutter the likelier; a tracked box next to another tracked box is two people), exponential
    averages as the other rates, with the Gamma prior of :func:`em_rate` (mean
    ``duplicate_prior``: nothing known, halfway; 0 turns the term off).  Where the detector
    boxes each person once, the pairs are people side by side and q sinks; where it often boxes
    a person twice q stays high (PETS09-S2L1's ACF: ~0.75; the soft count ``1 − won(z')``
    instead of the label gave ~0.6 and let second boxes through on PETS09-S3MF1)."""

    def __init__(self, cl: "ClutterParams", lk: "LikelihoodParams"):
        self.cl, self.lk = cl, lk
        self.q = float(cl.duplicate_prior)
        self.num = 0.0
        self.den = 0.0
        self._pairs: Optional[tuple] = None

    def log_kappa(self, Z: np.ndarray, log_v: Optional[np.ndarray] = None,
                  std: Optional[np.ndarray] = None) -> np.ndarray:
        """``log κ_d(z)`` (N_z,; ``-inf`` where z has no neighbour); ``log_v`` as
        :meth:`PlaceClutter.log_kappa`'s; ``std``: the detections' observation stds times
        :data:`NEAR_SCALE` (:meth:`NearClutter.wide_std_of`) when the caller has them."""
        n = self.counts(Z, std)
        if n is None:
            return np.full(len(Z), -np.inf)
        return kappa_terms(_log_v(Z, self.cl, self.lk, log_v), dup=(n, self.q))[2]

    def on(self, Z: np.ndarray) -> bool:
        """Whether the term is on for the detections ``Z`` (a prior, and a pair)."""
        return self.cl.duplicate_prior > 0 and len(Z) >= 2

    def counts(self, Z: np.ndarray, std: Optional[np.ndarray] = None,
               n: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
        """``n(z)`` (N_z,) int of :meth:`log_kappa`: the other detections in each widened
        gate (``n`` when the caller counted them: :func:`neighbour_counts`); None where the
        term is off (:meth:`on`).  Kept for :meth:`learn`."""
        self._pairs = None
        if not self.on(Z):
            return None
        std, r2 = _wide_gate(Z, self.cl, self.lk, NEAR_SCALE, std)
        if n is None:
            n = gate_sums(Z, Z, r2, std, np.ones(len(Z)), ordered=False)[2] - 1   # not z
        self._pairs = (Z, std, r2, n)
        return n

    def learn(self, won: np.ndarray, a: float) -> None:
        """After the update: ``won`` (N_z,) the detections' target shares."""
        if self.cl.duplicate_prior <= 0:
            return
        won = np.ascontiguousarray(won, dtype=np.float64)
        num = den = 0.0
        if self._pairs is not None and len(won):
            Z, std, r2, n = self._pairs
            # a neighbour is unexplained where the update found clutter the likelier (won < ½);
            # the sums count 0s and 1s (exact), z's own term taken off again
            lost = np.empty(len(won))
            tmp = np.empty((2, len(won)))
            if len(won) * len(won) < BRUTE_PAIRS:
                # few detections: gate_sums' brute pass (every pair, the same test) in the
                # same kernel call as the rest
                f = np.ascontiguousarray
                num, den = _dup_sums_brute(won, f(Z, dtype=np.float64),
                                           f(std, dtype=np.float64), float(r2), n, lost, tmp)
            else:
                _lost(won, lost)
                num, den = _dup_sums(won, lost,
                                     gate_sums(Z, Z, r2, std, lost, ordered=False)[0], n, tmp)
        self.em_step(a, num, den)

    def em_step(self, a: float, num: float, den: float) -> None:
        """The EM average of the duplicate probability q from this frame's sums (:meth:`learn`,
        and the fused :meth:`.filter.SceneModel.learn`)."""
        self.num = (1 - a) * self.num + a * num
        self.den = (1 - a) * self.den + a * den
        self.q = em_rate(self.num, self.den, self.cl.duplicate_prior, a)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _lost(won, lost):
    """``lost`` = 1.0 where ``won`` (clipped to [0, 1]) < ½, else 0.0."""
    for j in range(won.shape[0]):
        lost[j] = 1.0 if _clip01(won[j]) < 0.5 else 0.0


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _clip01(w):
    """np.clip(w, 0, 1) of a float (NaN stays NaN)."""
    return 0.0 if w < 0.0 else (1.0 if w > 1.0 else w)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _dup_sums(won, lost, near_lost, n, tmp):
    """:meth:`DuplicateBoxes.learn`'s ``Σ won · [a neighbour lost]`` and ``Σ won · [a
    neighbour]`` (``won`` clipped to [0, 1]; ``near_lost`` the lost count in each gate, z's own
    included), each summed as numpy's add.reduce; ``tmp`` (2, N_z) scratch."""
    m = np.int64(won.shape[0])
    for j in range(m):
        w = _clip01(won[j])
        tmp[0, j] = w * (1.0 if near_lost[j] - lost[j] > 0 else 0.0)
        tmp[1, j] = w * (1.0 if n[j] > 0 else 0.0)
    return _pairwise(tmp[0], m), _pairwise(tmp[1], m)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _dup_sums_brute(won, Z, std, r2, n, lost, tmp):
    """:func:`_lost`, the lost count in each detection's gate (:func:`.gating._gate_sums`'
    pass without a grid: every pair, as ``gate_sums(Z, Z, r2, std, lost, ordered=False)``
    does for few pairs; sums of 0s and 1s, exact in any order) and :func:`_dup_sums`, in one
    call."""
    _lost(won, lost)
    m = won.shape[0]
    near_lost, top, count = np.zeros(m), np.zeros(m), np.zeros(m, np.int64)
    no_grid = np.empty(0, np.int64)
    _gate_sums(Z, lost, lost, Z, std, r2, no_grid, no_grid, 0.0, 0.0, 1.0, 1.0, 0, 0,
               near_lost, top, count)
    return _dup_sums(won, lost, near_lost, n, tmp)


def _log_v(Z: np.ndarray, cl: "ClutterParams", lk: "LikelihoodParams",
           log_v: Optional[np.ndarray]) -> np.ndarray:
    """``log V(z)`` of the clutter gates (``log_v`` when the caller has it): ``−log`` of one
    clutter point spread as the ``gate`` model around each detection
    (:func:`.filter.log_clutter_density` at rate 1 is ``−log V``: the same floats)."""
    from .filter import log_gate_volume

    return log_gate_volume(Z, cl, lk) if log_v is None else log_v


_NO_F = np.zeros(0)
_NO_I = np.zeros(0, dtype=np.int64)
_NO_B = np.zeros(0, dtype=np.bool_)


def kappa_terms(log_v: np.ndarray, place: Optional[tuple] = None, near: Optional[tuple] = None,
                dup: Optional[tuple] = None, log_u: Optional[np.ndarray] = None) -> np.ndarray:
    """(5, N_z): ``log κ_r``, ``log κ_n``, ``log κ_d`` of the detections whose clutter gates
    have ``log V`` = ``log_v`` (-inf for a part not given), then, with ``log_u`` (the
    ``scene`` density κ_u, its near-people points included: :func:`scene_density`),
    ``log(κ_u + κ_r + κ_n + κ_d)`` (the shadow mixture) and ``log(κ_u + κ_n + κ_d)`` (the
    newborn's).  ``place`` = (S, E, β) (:meth:`PlaceClutter.
    place_rate`'s sums and prior), ``near`` = (M'(z), ν, chained or None), ``dup`` = (n(z),
    q).  One numba pass (:func:`_kappa_terms`) for what was ~30 numpy calls a frame: the same
    expressions elementwise (log, exp, log1p as numpy's, np.logaddexp's formula), so the
    same floats."""
    n_z = len(log_v)
    S, E, beta = place if place is not None else (_NO_F, _NO_F, 0.0)
    m, nu, chained = near if near is not None else (_NO_F, 0.0, None)
    n, q = dup if dup is not None else (_NO_I, 0.0)
    out = np.empty((5, n_z))
    _kappa_terms(log_v, S, E, PRIOR_FRAMES * beta, m, float(nu),
                 _NO_B if chained is None else chained, n, float(q),
                 _NO_F if log_u is None else log_u, out)
    return out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _kappa_terms(log_v, S, E, n0_beta, m, nu, chained, n, q, log_u, out):
    """:func:`kappa_terms` into ``out`` (5, N_z); empty ``S`` / ``m`` / ``n`` / ``log_u``:
    that part not given; empty ``chained``: none chained."""
    for j in range(log_v.shape[0]):
        unit = -log_v[j]
        lr = -np.inf
        if S.shape[0]:
            # (S + n0 β) / (E + n0), min(., 1) where S > 0 (np.minimum: NaN stays NaN)
            r = (S[j] + n0_beta) / (E[j] + PRIOR_FRAMES)
            rate = (1.0 if r > 1.0 else r) if S[j] > 0 else 0.0
            lr = np.log(rate) + unit
        ln = -np.inf
        if m.shape[0] and not (chained.shape[0] and chained[j]):
            mm = 1.0 if m[j] > 1.0 else m[j]
            ln = np.log(nu * mm) + unit
        ld = -np.inf
        if n.shape[0]:
            ld = np.log(q * n[j]) + unit
        out[0, j], out[1, j], out[2, j] = lr, ln, ld
        if log_u.shape[0]:
            u = log_u[j]
            out[3, j] = np.logaddexp(np.logaddexp(np.logaddexp(u, lr), ln), ld)
            out[4, j] = np.logaddexp(np.logaddexp(u, ln), ld)
        else:
            out[3, j] = out[4, j] = -np.inf


def _widened(lk: "LikelihoodParams", scale: float) -> "LikelihoodParams":
    """The likelihood with its observation stds times ``scale``."""
    return lk if scale == 1.0 else replace(lk, sigma_obs=lk.sigma_obs * scale,
                                           sigma_obs_min=lk.sigma_obs_min * scale)


def _wide_gate(Z: np.ndarray, cl: "ClutterParams", lk: "LikelihoodParams",
               scale: float, std: Optional[np.ndarray] = None) -> tuple[np.ndarray, float]:
    """The detections' observation stds times ``scale`` (``std`` when the caller has them)
    and the ``clutter_gate`` radius r²."""
    F = _filter
    if std is None:
        std = F.obs_std(Z[:, 2:4], _widened(lk, scale))
    return std, F.gate_threshold(cl.clutter_gate, F.OBS_DIM)


def neighbour_pairs(Z: np.ndarray, cl: "ClutterParams", lk: "LikelihoodParams",
                    scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) int arrays: the pairs of distinct detections of the frame with ``rows``
    inside the ``clutter_gate`` ellipsoid of ``cols``, its observation stds times ``scale``
    (grid-indexed pairs, :func:`.gating.gate_pairs`)."""
    from .gating import gate_pairs

    rows, cols = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    if len(Z) > 1:
        std, r2 = _wide_gate(Z, cl, lk, scale)
        for ch in gate_pairs(Z, Z, r2, std_z=std):
            other = ch.rows != ch.cols
            rows.append(ch.rows[other])
            cols.append(ch.cols[other])
    return np.concatenate(rows).astype(np.int64), np.concatenate(cols).astype(np.int64)


def neighbours(Z: np.ndarray, cl: "ClutterParams", lk: "LikelihoodParams",
               scale: float = 1.0, std: Optional[np.ndarray] = None) -> np.ndarray:
    """(N_z,) int: the other detections of the frame inside each detection's ``clutter_gate``
    ellipsoid, its observation stds times ``scale`` (the pairs of :func:`neighbour_pairs`,
    counted by :func:`.gating.gate_sums` without forming them).  ``std``: those stds when the
    caller has them."""
    if len(Z) < 2:
        return np.zeros(len(Z), dtype=np.int64)
    std, r2 = _wide_gate(Z, cl, lk, scale, std)
    return gate_sums(Z, Z, r2, std, np.ones(len(Z)), ordered=False)[2] - 1


def neighbour_counts(Z: np.ndarray, r2: float, std: np.ndarray,
                     wide: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`neighbours` of the detections ``Z`` (N_z >= 2) at two widths at once: the
    other detections inside each one's gate ``d² <= r2`` with the stds ``std`` and ``wide``
    (N_z, 4).  Below :data:`.gating.BRUTE_PAIRS` pairs one pass tests every pair for both
    (:func:`_count_two`: gate_sums' own test, so the same counts); above, two grid-indexed
    gate_sums."""
    from .gating import BRUTE_PAIRS

    n = len(Z)
    if n * n >= BRUTE_PAIRS:
        ones = np.ones(n)
        return (gate_sums(Z, Z, r2, std, ones, ordered=False)[2] - 1,
                gate_sums(Z, Z, r2, wide, ones, ordered=False)[2] - 1)
    c = np.empty((2, n), dtype=np.int64)
    f = np.ascontiguousarray
    _count_two(f(Z, dtype=np.float64), f(std, dtype=np.float64), f(wide, dtype=np.float64),
               float(r2), c)
    return c[0], c[1]


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _count_two(Z, std, wide, r2, c):
    """:func:`neighbour_counts`' pass: ``c[0, j]`` / ``c[1, j]`` the other detections inside
    detection j's gate with ``std`` / ``wide``."""
    n = Z.shape[0]
    for j in range(n):
        k0 = np.int64(-1)           # z itself is inside both
        k1 = np.int64(-1)
        for q in range(n):
            k0 += _in_gate(Z, q, Z, j, std, r2)
            k1 += _in_gate(Z, q, Z, j, wide, r2)
        c[0, j] = k0
        c[1, j] = k1


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _in_gate(P, q, Z, j, std, r2):
    """Whether point ``P[q]`` is inside detection ``Z[j]``'s gate ``d² <= r2`` of the stds
    ``std[j]``: gating._gate_sums' distance, term by term."""
    d0 = (P[q, 0] - Z[j, 0]) / std[j, 0]
    d1 = (P[q, 1] - Z[j, 1]) / std[j, 1]
    d2 = (P[q, 2] - Z[j, 2]) / std[j, 2]
    d3 = (P[q, 3] - Z[j, 3]) / std[j, 3]
    return d0 * d0 + d1 * d1 + d2 * d2 + d3 * d3 <= r2


#: :func:`_in_gate_early`'s first-coordinate bound is ``σ · √r² · (1 + GATE_MARGIN)``: wide
#: enough that a pair beyond it is out of the gate under any rounding of the exact test
GATE_MARGIN = 1e-9


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _in_gate_early(P, q, Z, j, std, r2, R):
    """:func:`_in_gate`, out at once when the first coordinates alone are farther apart than
    ``std[j, 0] · R`` (``R = √r2 · (1 + GATE_MARGIN)``: most pairs of the place memory are
    far apart): the same answer, as then ``d0²`` exceeds r2 by ~2·GATE_MARGIN, far above
    its rounding, and a float sum of non-negative terms is never below any of them
    (rounding is monotone).  A subtraction and a product instead of four divisions for a
    far pair; a bound below 1e-300 (denormal stds, never from obs_std's floor) or NaN
    rejects nothing (the exact test decides)."""
    lim = std[j, 0] * R
    if abs(P[q, 0] - Z[j, 0]) > lim and lim > 1e-300:
        return False
    return _in_gate(P, q, Z, j, std, r2)


def clutter_share(won: np.ndarray, log_used: np.ndarray, log_shadow: np.ndarray) -> np.ndarray:
    """Each detection's clutter share under the shadow model, ``κ_s / (κ_s + C)``, from ``won =
    C / (κ_used + C)`` of the update (which ran with κ_used)."""
    return learn_shares(won, log_used, log_shadow)[0][0]


def learn_shares(won: np.ndarray, log_used: np.ndarray, log_shadow: np.ndarray,
                 parts: Optional[tuple] = None, prev_link: Optional[np.ndarray] = None,
                 chain_clutter: Optional[np.ndarray] = None,
                 sums: Optional[np.ndarray] = None) -> tuple[np.ndarray, float]:
    """The EM's split of this frame's clutter (:meth:`.filter.SceneModel.learn`), in one numba
    pass (:func:`_learn_shares`; ~25 numpy calls a frame before, the same expressions
    elementwise and the same pairwise sum, so the same floats).  Returns ``out`` (5, N_z) and
    ``Σ share · κ_u / κ_s``: out[0] the clutter share ``κ_s / (κ_s + C)`` from ``won = C /
    (κ_used + C)`` (``won`` clipped to [0, 1]); with ``parts`` = (log κ_r, log κ_n, log κ_d)
    of :func:`kappa_terms` (``log_shadow`` their mixture), out[1] the place memory's weights
    ``share · (1 − r_n − r_d) · chain``, out[2] κ_r's shares ``share · r_r · chain``, out[3]
    κ_n's ``share · r_n`` (``r_x = κ_x / κ_s``, NaN -> 0) and out[4] ``chain · (1 − won)``,
    ``chain`` the last learnt frame's ``chain_clutter`` at ``prev_link`` (1 where a link is
    -1 or past its end, or without them).  ``sums`` (3,): also ``Σ share · κ_u / κ_s``,
    ``np.sum(out[2])`` and ``np.sum(out[3])`` written there (numpy's pairwise order, the same
    floats)."""
    won = np.ascontiguousarray(won, dtype=np.float64)
    log_used = np.ascontiguousarray(log_used, dtype=np.float64)
    log_shadow = np.ascontiguousarray(log_shadow, dtype=np.float64)
    n_z = len(won)
    log_rep, log_near, log_dup = parts if parts is not None else (_NO_F, _NO_F, _NO_F)
    use_chain = (prev_link is not None and chain_clutter is not None
                 and len(prev_link) == n_z and len(chain_clutter) > 0)
    out = np.empty((5, n_z))
    if sums is None:
        sums = np.empty(3)
    total = _learn_shares(won, log_used, log_shadow, log_rep, log_near, log_dup,
                          prev_link if use_chain else _NO_I,
                          chain_clutter if use_chain else _NO_F, out, sums)
    return out, total


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _learn_shares(won, log_used, log_shadow, log_rep, log_near, log_dup, prev_link,
                  chain_clutter, out, sums):
    """:func:`learn_shares` into ``out`` (5, N_z) and ``sums`` (3,); returns the random
    share's sum (0 without the parts)."""
    n_z = won.shape[0]
    random = np.empty(n_z)
    n_c = chain_clutter.shape[0]
    for j in range(n_z):
        w = _clip01(won[j])
        log_c = np.log(w) - np.log1p(-w) + log_used[j]      # log C(z)
        sh = 1.0 / (1.0 + np.exp(log_c - log_shadow[j]))
        if not math.isfinite(sh):
            sh = 0.0 if w >= 1.0 else 1.0
        out[0, j] = sh
        if log_rep.shape[0]:
            # the parts' shares of κ_s in [0, 1], NaN (-inf - -inf) -> 0
            rep = np.exp(log_rep[j] - log_shadow[j])
            near = np.exp(log_near[j] - log_shadow[j])
            dup = np.exp(log_dup[j] - log_shadow[j])
            rep = 0.0 if math.isnan(rep) else rep
            near = 0.0 if math.isnan(near) else near
            dup = 0.0 if math.isnan(dup) else dup
            chain = 1.0
            if prev_link.shape[0]:
                k = prev_link[j]
                if k >= 0 and k < n_c:
                    chain = chain_clutter[k]
            random[j] = sh * (1.0 - rep - near - dup)
            out[1, j] = sh * (1.0 - near - dup) * chain
            out[2, j] = sh * rep * chain
            out[3, j] = sh * near
            out[4, j] = chain * (1.0 - won[j])
        else:
            random[j] = 0.0
            out[1, j] = out[2, j] = out[3, j] = out[4, j] = 0.0
    total = _pairwise(random, n_z)
    sums[0] = total
    # (+ 0.0: numpy's sum of -0.0s is 0.0, the pairwise order's alone -0.0)
    sums[1] = _pairwise(out[2], n_z) + 0.0
    sums[2] = _pairwise(out[3], n_z) + 0.0
    return total


def scene_density(Z: np.ndarray, std: np.ndarray, m1: np.ndarray, m2: np.ndarray,
                  extent: np.ndarray, a: float, see: bool, log_rate: float, area: float,
                  log_v0: float, floor: float, near_rate: float = 0.0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """:class:`~.filter.SceneModel`'s ``scene`` density of the detections ``Z`` (N_z, 4) in
    one numba pass (:func:`_scene_density`; ~35 numpy and LAPACK calls a frame before): with
    ``see``, first their extent into ``extent`` (x0, y0, x1, y1) and the exponential averages
    (weight ``a``) of the log sizes' moments ``m1`` (2,), ``m2`` (2, 2), in place; then ``log
    κ_u(z) = log_rate − log A + log N(log(w, h); m1, cov) − log w − log h`` (uniform over the
    image of area A = ``area`` when > 0, else the extent's ``max(w, 1) max(h, 1)``, 1 before
    any extent; the log-normal size density, ``cov = m2 − m1 m1ᵀ + floor I``, its 2 × 2
    inverse and determinant in closed form), with ``near_rate`` > 0 plus that many points
    spread as the ``gate`` model around each detection (``log(κ_u + near_rate / V(z))``, as
    np.logaddexp), and the clutter gates' ``log V(z) = log_v0 + Σ_d log σ_d`` of the stds
    ``std`` (N_z, 4).  Returns (log κ_u, log V)."""
    out = np.empty((2, len(Z)))
    _scene_density(np.ascontiguousarray(Z, dtype=np.float64),
                   np.ascontiguousarray(std, dtype=np.float64), m1, m2, extent, float(a),
                   bool(see), float(log_rate), float(area), float(log_v0), float(floor),
                   math.log(near_rate) if near_rate > 0 else 0.0, near_rate > 0, out)
    return out[0], out[1]


def scene_terms(density: tuple, mem_z: np.ndarray, mem_w: np.ndarray, mem_e: np.ndarray,
                r2: float, beta: float, near: Optional[tuple] = None,
                dup: Optional[tuple] = None) -> np.ndarray:
    """:func:`scene_density` of the arguments ``density`` (its in-place updates included),
    the place memory's ``S(z)``, ``E(z)`` in each detection's clutter gate (``r2``; the
    memory ``mem_z``, ``mem_w``, ``mem_e``: :meth:`PlaceClutter._weight_in_gates`, by
    :func:`.gating.gate_sums`' grid pass) and :func:`kappa_terms` of them with ``place`` =
    (S, E, ``beta``), ``near``, ``dup`` and ``log_u`` = log κ_u, in one call
    (:func:`_scene_terms`) for what were three kernels and their wrappers: the same floats.
    Returns (7, N_z): log κ_u, log V, then kappa_terms' five rows.  Where gate_sums' one-pass
    grid declines (non-finite values, a sparse grid), its GridIndex path and kappa_terms
    follow in Python."""
    Z, std, m1, m2, extent, a, see, log_rate, area, log_v0, floor, near_rate = density
    f = np.ascontiguousarray
    Z, std = f(Z, dtype=np.float64), f(std, dtype=np.float64)
    mem_z, mem_w, mem_e = (f(mem_z, dtype=np.float64), f(mem_w, dtype=np.float64),
                           f(mem_e, dtype=np.float64))
    m, nu, chained = near if near is not None else (_NO_F, 0.0, None)
    n, q = dup if dup is not None else (_NO_I, 0.0)
    chained = _NO_B if chained is None else chained
    out = np.empty((7, len(Z)))
    if _scene_terms(Z, std, m1, m2, extent, float(a), bool(see), float(log_rate), float(area),
                    float(log_v0), float(floor),
                    math.log(near_rate) if near_rate > 0 else 0.0, near_rate > 0,
                    mem_z, mem_w, mem_e, float(r2), PRIOR_FRAMES * beta, m, float(nu),
                    chained, n, float(q), out):
        return out
    S, E, _ = gate_sums(mem_z, Z, r2, std, mem_w, mem_e)
    _kappa_terms(out[1], S, E, PRIOR_FRAMES * beta, m, float(nu), chained, n, float(q),
                 out[0], out[2:])
    return out


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _scene_terms(Z, std, m1, m2, extent, a, see, log_rate, area, log_v0, floor, log_near_rate,
                 near_on, mem_z, mem_w, mem_e, r2, n0_beta, m, nu, chained, n, q, out):
    """:func:`scene_terms` into ``out`` (7, N_z); False (the density written, the rest not)
    where gate_sums' one-pass grid declines."""
    nz = Z.shape[0]
    _scene_density(Z, std, m1, m2, extent, a, see, log_rate, area, log_v0, floor,
                   log_near_rate, near_on, out[0:2])
    S = np.zeros(nz)
    E = np.zeros(nz)
    if mem_z.shape[0] and nz:
        C = np.zeros(nz, np.int64)
        if not _gate_sums_cells(mem_z, mem_w, mem_e, Z, std, r2, S, E, C):
            return False
    _kappa_terms(out[1], S, E, n0_beta, m, nu, chained, n, q, out[0], out[2:7])
    return True


#: :func:`scene_frame`'s scalars (``par``): their places
(P_R2, P_A_NEAR, P_NEAR, P_A, P_SEE, P_LOG_RATE, P_AREA, P_LOG_V0, P_FLOOR, P_N0_BETA, P_NU, P_Q,
 P_RATIO, P_SCORE_FLOOR, P_USE_PSUMS, P_CLIP, P_PERSIST) = range(17)
N_SCENE_PAR = 17


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _two_class_fit(S, floor):
    """:meth:`.filter.SceneModel._two_class_fit` of the sums ``S`` (2, 3) (the same
    operations on the same float64 values: the same floats): ``(ok, d'², slope, midpoint)``,
    ok False where it gives None."""
    a0, a1, a2, b0, b1, b2 = S[0, 0], S[0, 1], S[0, 2], S[1, 0], S[1, 1], S[1, 2]
    m0, m1 = a1 / a0, b1 / b0
    if not m0 > m1:
        return False, 0.0, 0.0, 0.0
    var = ((a2 - a1 * a1 / a0) + (b2 - b1 * b1 / b0)) / (a0 + b0)
    var = floor if floor > var else var          # Python's max(var, floor)
    gap = m0 - m1
    return True, gap * gap / var, gap / var, 0.5 * (m0 + m1)


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def scene_frame(states, w, Z, std, length, scores, par, m1, m2, extent, mem_z, mem_w, mem_e,
                score_sums, persist_sums, pos_ext):
    """:meth:`.filter.SceneModel.log_kappa` of the ``learn`` / ``model`` mixture after the
    chains, in one call (what were ~8 kernel and numpy calls a frame): the wide stds ``std ·``
    :data:`NEAR_SCALE` (:meth:`NearClutter.wide_std_of`), ``chained`` / ``persist`` (the chain
    ``length`` >= 1 / >= ``par[P_PERSIST]``; ``w`` the particles' weights, or their one value
    (1,) when they are all equal), :func:`neighbour_counts`' brute pass
    (:func:`_count_two`; N_z² < BRUTE_PAIRS; a lone detection counts 0), the near-rate
    average, κ_n's M'(z) and the birth's M(z) (:func:`._kernels.mass_near_two` on
    :func:`._kernels.grid_cell`'s cells), :func:`_scene_terms` and, with ``par[P_RATIO]``, the
    score fit of ``score_sums`` (and ``persist_sums`` with ``par[P_USE_PSUMS]``) and its ratio
    ``clip(slope (s − mid), ±c)`` taken off the mixture (:meth:`.filter.SceneModel.
    log_score_ratio`).  ``pos_ext``: the particles' position extent as the prediction made
    it (:func:`._kernels.propagate_into`; empty: none, the grid makes it).  The same
    operations in the same order: the same floats.  Returns
    ``(code, near, wide, chained, persist, n_dup, m, grid, m_near, out, final)``: code 0
    non-finite particle positions (nothing after M(z) computed), 2 gate_sums' one-pass grid
    declined (``out`` holds the density only: the caller finishes), 1 done; ``out`` (7, N_z) as
    :func:`scene_terms`' and ``final`` the mixture minus the score ratio."""
    nz = Z.shape[0]
    r2 = par[P_R2]
    wide = np.empty((nz, 4))
    chained = np.empty(nz, np.bool_)
    persist = np.empty(nz, np.bool_)
    for j in range(nz):
        for c in range(4):
            wide[j, c] = std[j, c] * NEAR_SCALE
        chained[j] = length[j] >= 1
        persist[j] = length[j] >= par[P_PERSIST]
    cnt = np.empty((2, nz), np.int64)
    _count_two(Z, std, wide, r2, cnt)
    tot = np.int64(0)
    for j in range(nz):
        tot += cnt[0, j]
    a = par[P_A_NEAR]
    near = (1 - a) * par[P_NEAR] + a * (tot / nz)
    cell = _kernels.grid_cell(std, r2)
    code, m, grid, m_near = _kernels.mass_near_two_at(states, w, Z, std, r2, cell[0], cell[1],
                                                      wide, chained, pos_ext)
    out = np.empty((7, nz))
    final = np.empty(nz)
    if not code:
        return 0, near, wide, chained, persist, cnt[1], m, grid, m_near, out, final
    near_on = near > 0
    if not _scene_terms(Z, std, m1, m2, extent, par[P_A], par[P_SEE] != 0.0, par[P_LOG_RATE],
                        par[P_AREA], par[P_LOG_V0], par[P_FLOOR],
                        np.log(near) if near_on else 0.0, near_on, mem_z, mem_w, mem_e, r2,
                        par[P_N0_BETA], m_near, par[P_NU], chained, cnt[1], par[P_Q], out):
        return 2, near, wide, chained, persist, cnt[1], m, grid, m_near, out, final
    ok = False
    slope = mid = 0.0
    if par[P_RATIO] != 0.0:
        # SceneModel._score_fit: the fit on the mass, or on persistence where that one
        # separates the classes more
        ok, d2, slope, mid = _two_class_fit(score_sums, par[P_SCORE_FLOOR])
        if par[P_USE_PSUMS] != 0.0:
            ok_p, d2_p, slope_p, mid_p = _two_class_fit(persist_sums, par[P_SCORE_FLOOR])
            if not ok or (ok_p and d2_p > d2):
                ok, slope, mid = ok_p, slope_p, mid_p
    if ok:
        c = par[P_CLIP]
        for j in range(nz):
            v = slope * (scores[j] - mid)
            # np.clip(v, -c, c) (NaN stays NaN)
            v = -c if v < -c else v
            v = c if v > c else v
            final[j] = out[5, j] - v
    else:
        for j in range(nz):
            final[j] = out[5, j] - 0.0
    return 1, near, wide, chained, persist, cnt[1], m, grid, m_near, out, final


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _scene_density(Z, std, m1, m2, extent, a, see, log_rate, area, log_v0, floor,
                   log_near_rate, near_on, out):
    """:func:`scene_density` into ``out`` (2, N_z)."""
    n = Z.shape[0]
    if see and n:
        x0, y0, x1, y1 = extent[0], extent[1], extent[2], extent[3]
        s0 = s1 = q00 = q01 = q11 = 0.0
        for j in range(n):
            hw, hh = Z[j, 2] / 2, Z[j, 3] / 2
            lo, hi = Z[j, 0] - hw, Z[j, 0] + hw
            x0 = lo if lo < x0 else x0
            x1 = hi if hi > x1 else x1
            lo, hi = Z[j, 1] - hh, Z[j, 1] + hh
            y0 = lo if lo < y0 else y0
            y1 = hi if hi > y1 else y1
            l0, l1 = np.log(Z[j, 2]), np.log(Z[j, 3])
            s0 += l0
            s1 += l1
            q00 += l0 * l0
            q01 += l0 * l1
            q11 += l1 * l1
        extent[0], extent[1], extent[2], extent[3] = x0, y0, x1, y1
        b = 1.0 - a
        m1[0] = b * m1[0] + a * (s0 / n)
        m1[1] = b * m1[1] + a * (s1 / n)
        m2[0, 0] = b * m2[0, 0] + a * q00 / n
        m2[1, 1] = b * m2[1, 1] + a * q11 / n
        m2[0, 1] = m2[1, 0] = b * m2[0, 1] + a * q01 / n
    c00 = m2[0, 0] - m1[0] * m1[0] + floor
    c11 = m2[1, 1] - m1[1] * m1[1] + floor
    c01 = 0.5 * ((m2[0, 1] - m1[0] * m1[1]) + (m2[1, 0] - m1[1] * m1[0]))
    det = c00 * c11 - c01 * c01
    if not area > 0:
        area = 1.0
        if extent[0] <= extent[2]:
            w, h = extent[2] - extent[0], extent[3] - extent[1]
            area = (w if w > 1.0 else 1.0) * (h if h > 1.0 else 1.0)
    const = -math.log(2 * math.pi) - 0.5 * np.log(det) + (log_rate - np.log(area))
    for j in range(n):
        l0, l1 = np.log(Z[j, 2]), np.log(Z[j, 3])
        d0, d1 = l0 - m1[0], l1 - m1[1]
        quad = (d0 * d0 * c11 - 2.0 * d0 * d1 * c01 + d1 * d1 * c00) / det
        lv = log_v0 + (((np.log(std[j, 0]) + np.log(std[j, 1])) + np.log(std[j, 2]))
                       + np.log(std[j, 3]))
        u = -0.5 * quad + const - (l0 + l1)
        out[0, j] = np.logaddexp(u, log_near_rate - lv) if near_on else u
        out[1, j] = lv


# the filter module (observation stds, gate radii), bound here once: filter imports this module
# at its top, so either is loaded first; read at call time (no import statement per call)
from . import filter as _filter  # noqa: E402
