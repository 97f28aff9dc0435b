"""SMC-PHD filter on detections — maggio2007 §2 (recursion, eqs. (1)–(5)) with the §4 settings.

State ``x = (y1, y2, v1, v2, w, h)`` (box centre px, velocity px/frame, box size px);
observation ``z = (y1, y2, w, h)`` (``Detections.observations()``).  The PHD is carried by a
:class:`~trackers.smc.ParticleSet` whose total weight is the expected number of targets.

One frame is four pure functions, each returning new arrays (the lead's tracker logs every
stage from :class:`PHDStepResult`):

1. :func:`predict` — eqs. (1), (2), (4) for the L_{k-1} persistent particles: propagate with
   the size-aware motion model (importance function q = f, no spawning), weight × e = 0.99.
2. :func:`birth` — J_k newborn particles drawn around the detections (§2 last paragraph).
3. :func:`update` — eq. (5), on the (particle, detection) pairs inside the update gate
   (:mod:`.gating`), or on a dense (N particles × N_z detections) matrix.
4. :func:`resample` — L_k = ρ M̂_{k|k} particles, total mass preserved.

Cost linear in the number of targets (DESIGN.md "gating"): g(z|x) is evaluated only on the pairs
inside a generous observation-noise gate of each detection (a grid index on the particles'
positions; the dropped likelihood is below 3e-14 of its peak, so the results are those of the
dense eq. (5) up to float noise — the bound is in :mod:`.gating`), M(z) goes through the same
kind of index, and the newborn per frame are capped (``max_births_per_frame``).  For the
Gaussian g of the paper the stages are fused numba kernels (:mod:`._kernels`: predict, M(z),
the newborn, eq. (5) evaluated inside the gates with no pair arrays, so memory is O(N + N_z)
whatever the number of detections); a likelihood of another kind goes through
:func:`gated_log_g`, whose memory is bounded by ``pair_budget`` candidate pairs at a time.

Readings of the paper (each a :class:`PHDParams` field):

- **Likelihood** g(z|x) (§2, §4): Gaussian on ``(y1, y2, w, h)`` with diagonal std
  ``σ_w = max(0.15 w, 1)``, ``σ_h = max(0.15 h, 1)``, ``σ_y1 = σ_w/2``, ``σ_y2 = σ_h/2``.
  §2 says the stds are "proportional to the sizes w and h of each z", §4 writes ``w_{k-1}``;
  we use the detection's size (``obs_std_source="detection"``); ``"particle"`` uses each
  particle's size instead.
- **Clutter** κ(z) must be a density in observation space (DESIGN.md).  §4: "the intensity of
  clutter around the detections is 1.0 clutter point per frame".  Read as
  ``κ(z) = clutter_rate / V(z)`` with ``V(z)`` the volume of the ``clutter_gate`` (99%)
  confidence ellipsoid of the observation noise around z in the 4-D observation space.
  For a Gaussian g the peak is ``(2π)^-2 / Πσ`` and ``V = (π²/2) r⁴ Πσ`` (``r² = χ²₄(0.99)``),
  so ``κ / max g = 8 / r⁴ ≈ 0.045`` whatever the box size.  Consequence (checked in the tests):
  one isolated detection gives its newborn cloud only ~5% mass, and 3–4 coherent consecutive
  detections are needed to exceed T = 0.6 — the behaviour §4 describes.  The price: a
  well-detected target's mass settles near 0.8, not 1/(1 − p_M e) ≈ 1.05, because its
  predicted cloud is about as wide as the observation noise, so ``C(z) ≈ 4–5 κ(z)`` and each
  detection adds ``C/(κ + C) ≈ 0.8`` (M̂ under-counts by ~20%; ``clutter_rate → 0`` gives 1.05).
- **Birth allocation** "J_z = J_max(1 − I_max) M(z)" (garbled in our copy) is read as
  ``J_z = J_max · max(0, 1 − M(z))`` (DESIGN.md), M(z) = predicted mass inside the ``gate``
  (99%) Mahalanobis gate of z under the observation noise (``birth_allocation="complement"``;
  ``"constant"`` gives J_max to every detection).
- **Birth weights**: each detection's J_z newborn share a total weight ``birth_intensity``
  (0.01 "targets per frame per detection", §4), i.e. eq. (4) with γ_z ∝ p_z so that
  γ/(J p) is constant.  Newborn ``(y, w, h)`` are drawn from ``N(z, (birth_spread·σ(z))²)`` —
  the "mixture of Gaussians centred on the observations" — velocity direction uniform and
  amplitude Gaussian ``N(birth_speed_mean·s, (birth_speed_std·s)²)`` with
  ``s = sqrt(w_z h_z)`` (the paper gives no values; scaling by the box size follows its
  size-proportional noise; a negative amplitude is the opposite direction, so no clipping).
- **Birth cap** (not in the paper): at most ``max_births_per_frame`` newborn per frame; above
  it every J_z is scaled by the same factor (rounded down), so a storm of clutter detections
  costs a bounded amount.  Each detection's newborn still carry ``birth_intensity`` in total.
  The default (50,000 = 50 fresh detections at J_max) never binds on scenes of a few targets.
- **Resampling**: ``L_k = round(ρ M̂_{k|k})`` clipped to ``[min_particles, max_particles]``
  (a cap the paper does not have, for memory safety), each weight ``M̂_{k|k} / L_k``.

Scene clutter (``clutter_model="scene"``, ``birth_odds``, ``score_model``; the ``practical``
preset of :mod:`.tracker`, not in the paper).  The §4 reading above puts 1 clutter point per
frame *around every detection*, so a well-detected target keeps ~0.8 of its mass and one miss
cuts it ~20×.  Instead κ(z) can be a density over the whole observation space that matches the
data: ``κ(z) = λ · 1/A · p(w, h)`` (A the image area, p a log-normal fitted online to the
detections' sizes, λ re-estimated each frame as ``Σ_z κ/(κ + C)``, the EM step for the rate of
Poisson clutter; :class:`SceneModel`), optionally plus ``near_rate`` points around each
detection (false boxes next to people), itself estimated online with ``near_learn``.  The
newborn must then weigh in proportion to κ (``birth_odds``, :func:`log_birth_weight`): a
detection no existing target explains gives its newborn mass ``odds/(1 + odds)``, so isolated
clutter adds little, while a second coherent detection confirms a target.  On the synthetic
scene (p_D 0.9, 5 clutter boxes a frame) the mass then follows the true count within ~5%
(``tests/test_phd_practical.py``).  Detection scores enter as a likelihood ratio on κ
(:class:`ScoreParams`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache, partial
from typing import Iterable, Iterator, Optional, Protocol, Union

import numpy as np
from numba import njit

from ..params import param, part, with_options
from . import _kernels, motion
from .clutter import PlaceClutter
from .clutter import _log_count
from .clutter import (DuplicateBoxes, NearClutter, kappa_terms, learn_shares, neighbour_counts,
                      scene_density, scene_terms, scene_frame, neighbours, _kappa_terms,
                      PRIOR_FRAMES, MIN_WEIGHT, INCREMENT_PAIRS, _learn_shares,
                      _memory_step, _dup_sums_brute, _NO_I, _NO_F)
from .clutter import (N_SCENE_PAR, P_R2, P_A_NEAR, P_NEAR, P_A, P_SEE, P_LOG_RATE, P_AREA,
                      P_LOG_V0, P_FLOOR, P_N0_BETA, P_NU, P_Q, P_RATIO, P_SCORE_FLOOR,
                      P_USE_PSUMS, P_CLIP, P_PERSIST)
from .scene_motion import Chains
from .gating import BRUTE_PAIRS, DEFAULT_BUDGET, LogGPairs, gate_pairs, gate_sums, tail_radius2
from ..smc.resampling import SCHEMES
from ..smc.resampling import resample as _resample_set
from ..smc.random import key_stream
from ..smc.weights import LazyParticleSet, ParticleSet, logsumexp
from ..types import Frame

#: Columns of the state that the detector observes: (y1, y2, w, h).
OBS_COLS = (0, 1, 4, 5)
STATE_DIM = 6
OBS_DIM = 4


def _check(obj, name: str, ok: bool, rule: str) -> None:
    if not ok:
        raise ValueError(f"{type(obj).__name__}.{name} must be {rule}, got {getattr(obj, name)!r}")


@dataclass(frozen=True)
class MotionParams:
    """Prediction: survival and the size-aware motion model (:mod:`.motion`)."""

    p_survival: float = param(0.99, "survival probability e_{k|k-1}", paper="maggio2007 §4")
    sigma_v: float = param(motion.SIGMA_V, "acceleration std per frame, as a fraction of w / h",
                           paper="maggio2007 §4")
    sigma_size: float = param(motion.SIGMA_SIZE, "size-change std per frame, fraction of w / h",
                              paper="maggio2007 §4")
    accel_to_position: float = param(motion.ACCEL_TO_POSITION,
                                     "y += v + c·a: share of the acceleration reaching the "
                                     "position within the frame (reading: dt²/2)")
    min_size: float = param(motion.MIN_SIZE, "boxes are clipped to at least this many pixels")

    def __post_init__(self):
        _check(self, "p_survival", 0.0 <= self.p_survival <= 1.0, "in [0, 1]")
        for name in ("sigma_v", "sigma_size"):
            _check(self, name, getattr(self, name) >= 0, ">= 0")
        _check(self, "min_size", self.min_size > 0, "> 0")


@dataclass(frozen=True)
class LikelihoodParams:
    """Detection model: p_M and the Gaussian g(z|x) of maggio2007 §2/§4.  Its observation-noise
    stds also size the birth gate, the clutter volume and the K-means distances."""

    p_miss: float = param(0.05, "probability of missed detection p_M (uniform)",
                          paper="maggio2007 §4")
    sigma_obs: float = param(0.15, "observation std of w, h as a fraction of the size",
                             paper="maggio2007 §4")
    sigma_obs_min: float = param(1.0, "floor of the size std, pixels", paper="maggio2007 §4")
    sigma_obs_pos_ratio: float = param(0.5, "σ_y = ratio · σ_size", paper="maggio2007 §4")
    obs_std_source: str = param("detection", "size the stds by the 'detection' (§2) or by each "
                                             "'particle' (§4 w_{k-1})")

    def __post_init__(self):
        _check(self, "p_miss", 0.0 <= self.p_miss <= 1.0, "in [0, 1]")
        for name in ("sigma_obs", "sigma_obs_min", "sigma_obs_pos_ratio"):
            _check(self, name, getattr(self, name) > 0, "> 0")
        _check(self, "obs_std_source", self.obs_std_source in ("detection", "particle"),
               "'detection' or 'particle'")


@dataclass(frozen=True)
class ClutterParams:
    """κ(z), a density in observation space (DESIGN.md).  ``gate`` (maggio2007 §4 reading):
    rate / volume of a gate around z.  ``scene``: clutter_rate points per frame spread over
    the whole observation space -- uniform over the image, log-normal over the box size
    (w, h) fitted online to the detections -- with the rate re-estimated online (module
    docstring, "Scene clutter")."""

    clutter_rate: float = param(1.0, "clutter points per frame around a detection ('gate'); "
                                     "per frame in the whole image ('scene': the prior of the "
                                     "online estimate)", paper="maggio2007 §4")
    clutter_gate: float = param(0.99, "confidence of the ellipsoid V(z) in κ = rate / V "
                                      "(reading; 'gate' only)")
    clutter_model: str = param("gate", "'gate': κ(z) = clutter_rate / V(z) (§4 reading); "
                                       "'scene': a density over the image and the box sizes, "
                                       "rate estimated online; 'learn': 'scene' plus 'gate' "
                                       "where clutter fell before, the mix learnt online "
                                       "(.clutter; not in paper)")
    near_rate: float = param(0.0, "'scene': plus this many clutter points per frame around "
                                  "each detection, spread as in 'gate' (duplicate or "
                                  "misplaced boxes near people; not in paper)")
    near_learn: bool = param(False, "'scene': estimate near_rate online (near_rate is the "
                                    "prior) as the mean number of other detections of the "
                                    "same frame inside a detection's clutter_gate")
    clutter_memory: float = param(100.0, "'scene': frames the online estimates (clutter rate, "
                                         "size distribution, score model) average over")
    repeat_prior: float = param(1.0, "'learn': prior share β of clutter that comes back in "
                                     "place (1: the 'gate' model wherever clutter fell)")
    repeat_memory: float = param(0.1, "'learn': how long the places where clutter fell are "
                                      "remembered, as a fraction of clutter_memory")
    learn_update: str = param("gate", "'learn': the κ of the update -- 'gate': the random "
                                      "density plus the 'gate' model at the learnt share of "
                                      "structured clutter around every detection (the "
                                      "structured clutter not placed yet); 'model': the "
                                      "learnt mixture itself, second boxes on one person "
                                      "included (.clutter)")
    duplicate_prior: float = param(0.5, "'learn' with learn_update 'model': prior mean of q, "
                                        "the extra boxes a detector puts on a person it "
                                        "already boxed, per detected person and frame "
                                        "(learnt online; 0: no duplicate term; .clutter)")

    spot_places: bool = param(False, "'learn' with learn_update 'model': a place's clutter "
                                     "memory counts a detection that continues a chain by the "
                                     "probability that its chain so far is clutter (the "
                                     "product of its detections' clutter shares 1 - won: a "
                                     "spot's chain stays clutter, a person's stops being "
                                     "clutter once it wins mass), and newborns weigh against "
                                     "κ without the place memory (people do not appear more "
                                     "often where clutter repeats; .clutter)")

    def __post_init__(self):
        _check(self, "clutter_rate", self.clutter_rate >= 0, ">= 0")
        _check(self, "clutter_gate", 0.0 < self.clutter_gate < 1.0, "in (0, 1)")
        _check(self, "clutter_model", self.clutter_model in ("gate", "scene", "learn"),
               "'gate', 'scene' or 'learn'")
        _check(self, "repeat_prior", 0.0 <= self.repeat_prior <= 1.0, "in [0, 1]")
        _check(self, "repeat_memory", self.repeat_memory > 0, "> 0")
        _check(self, "learn_update", self.learn_update in ("gate", "model"), "'gate' or 'model'")
        _check(self, "clutter_memory", self.clutter_memory >= 1, ">= 1")
        _check(self, "duplicate_prior", 0.0 <= self.duplicate_prior <= 1.0, "in [0, 1]")
        _check(self, "near_rate", self.near_rate >= 0, ">= 0")


@dataclass(frozen=True)
class ScoreParams:
    """Detection scores in the update (not in maggio2007; amplitude-aided PHD, Clark et al.
    2010): each detection's clutter intensity is divided by the likelihood ratio
    ``p(s | target) / p(s | clutter)`` of its score s, two Gaussians of one pooled variance
    fitted online (EM: each detection counts as target by the mass it won, C/(κ + C)); the
    ratio is 1 until targets score higher than clutter on average.  Scores need no scale: the fit
    is per detector, on whatever the detector outputs.

    Bootstrap by persistence (``persist_frames`` > 0): the mass a detection wins is a poor
    label while the filter holds no target (a scene where every newborn cloud misses the next
    detection keeps ``won`` near the birth odds, and the two classes never separate).  A second
    fit of the same two Gaussians labels the detections by persistence instead: target when it
    continues a chain of mutually nearest detections over ``persist_frames`` earlier frames
    (:class:`~.scene_motion.Chains`), clutter otherwise.  Both labellings are noisy versions
    of the true classes, and label noise pulls the fitted class means together, so the fit
    whose means lie further apart (in within-class stds, d') has the cleaner labels: the
    ratio comes from that one.  Where the filter tracks, the mass separates the classes
    better (persistent false detections -- a detector firing on the same spot -- are labelled
    target by persistence); where it holds nothing yet, persistence does.  On the development
    set chained detections score like the ones matched to a person and unchained like the
    false ones."""

    score_model: str = param("none", "'none': scores ignored (paper); 'gaussian': p_D and κ "
                                     "as functions of the score (online two-class fit)")
    score_prior: float = param(20.0, "pseudo-detections per class of the prior (both classes "
                                     "start at the scores of the first frame: ratio 1)")
    max_log_ratio: float = param(4.6, "|log p(s|target)/p(s|clutter)| is clipped here "
                                      "(4.6 ≈ a factor 100)")
    persist_frames: int = param(0, "> 0: a detection that continues a chain of mutually "
                                   "nearest detections over this many earlier frames counts "
                                   "as a target in the score fit even when it won no mass "
                                   "(learns the score classes before any track; "
                                   "phd.scene_motion.Chains); 0: mass only")

    def __post_init__(self):
        _check(self, "score_model", self.score_model in ("none", "gaussian"),
               "'none' or 'gaussian'")
        _check(self, "score_prior", self.score_prior > 0, "> 0")
        _check(self, "max_log_ratio", self.max_log_ratio >= 0, ">= 0")
        _check(self, "persist_frames", self.persist_frames >= 0, ">= 0")


@dataclass(frozen=True)
class BirthParams:
    """Newborn particles around the detections (maggio2007 §2, readings in the module doc)."""

    j_max: int = param(1000, "newborn particles per detection at most", paper="maggio2007 §4")
    birth_intensity: float = param(0.01, "targets per frame per detection (newborn mass)",
                                   paper="maggio2007 §4")
    gate: float = param(0.99, "confidence of the gate for M(z), the mass near z",
                        paper="maggio2007 §2")
    birth_allocation: str = param("complement", "'complement': J_z = J_max max(0, 1 − M(z)) "
                                                "(DESIGN reading); 'constant': J_max")
    birth_spread: float = param(1.0, "newborn (y, w, h) std / observation std (not in paper)")
    birth_speed_mean: float = param(0.0, "newborn speed mean / sqrt(w h) per frame "
                                         "(not in paper)")
    birth_speed_std: float = param(0.1, "newborn speed std / sqrt(w h) per frame (not in paper)")
    birth_odds: float = param(0.0, "0: each detection's newborn weigh birth_intensity "
                                    "(paper); > 0: their weight is set from κ(z) so that a "
                                    "detection no target explains gives its newborn this "
                                    "odds of target against clutter, C_b/κ (not in paper)")
    revive_odds: float = param(0.0, "with birth_odds > 0: the odds given instead to a "
                                    "detection the tracker marks as the return of a confirmed "
                                    "track that lost its estimate (inside the gate of its "
                                    "prediction; PHDTracker), so one miss does not cost the "
                                    "slow re-birth of a new target (0: off; not in paper)")
    max_births_per_frame: int = param(50_000, "newborn particles per frame at most: above it "
                                              "every J_z is scaled down by the same factor "
                                              "(not in paper; bounds a clutter storm)")

    def __post_init__(self):
        _check(self, "j_max", self.j_max >= 0, ">= 0")
        _check(self, "birth_intensity", self.birth_intensity > 0, "> 0")
        _check(self, "gate", 0.0 < self.gate < 1.0, "in (0, 1)")
        _check(self, "birth_allocation", self.birth_allocation in ("complement", "constant"),
               "'complement' or 'constant'")
        _check(self, "birth_spread", self.birth_spread > 0, "> 0")
        _check(self, "birth_speed_std", self.birth_speed_std >= 0, ">= 0")
        _check(self, "max_births_per_frame", self.max_births_per_frame >= 0, ">= 0")
        _check(self, "revive_odds", self.revive_odds >= 0, ">= 0")
        _check(self, "birth_odds", self.birth_odds >= 0, ">= 0")


@dataclass(frozen=True)
class ResamplingParams:
    """L_k = ρ M̂ particles after each update, each weighing M̂ / L_k (maggio2007 §2)."""

    rho: float = param(1500.0, "particles per target, L_k = ρ M̂", paper="maggio2007 §4")
    resampling: str = param("systematic", f"scheme: {', '.join(SCHEMES)}")
    min_particles: int = param(1, "L_k lower bound (1: the mass is always preserved)")
    max_particles: int = param(100_000, "L_k upper bound, for memory (≈ 66 targets at ρ = 1500)")

    def __post_init__(self):
        _check(self, "rho", self.rho > 0, "> 0")
        _check(self, "resampling", self.resampling in SCHEMES, f"one of {', '.join(SCHEMES)}")
        _check(self, "min_particles", 0 <= self.min_particles <= self.max_particles,
               "in [0, max_particles]")


@dataclass(frozen=True)
class GatingParams:
    """Which (particle, detection) pairs eq. (5) evaluates (not in the paper: a speed-up that
    leaves the results unchanged up to float noise; the bound is in :mod:`.gating`)."""

    gate_tail: float = param(1e-12, "update gate: pairs beyond χ²₄⁻¹(1 − tail) Mahalanobis² "
                                    "of the observation noise get g = 0 (there g < 3e-14 "
                                    "of its peak at 1e-12)")
    pair_budget: int = param(DEFAULT_BUDGET, "candidate (particle, detection) pairs handled at "
                                             "once: bounds the update's memory (~150 B each) "
                                             "for a likelihood other than the Gaussian")

    def __post_init__(self):
        _check(self, "gate_tail", 0.0 < self.gate_tail < 1.0, "in (0, 1)")
        _check(self, "pair_budget", self.pair_budget >= 1, ">= 1")


@dataclass(frozen=True)
class PHDParams:
    """The particle PHD filter, in parts; defaults are maggio2007 §4 (or §2) unless noted.
    ``with_options(PHDParams(), {"p_miss": 0.2})`` or :meth:`of` set single fields."""

    motion: MotionParams = part(MotionParams, "prediction: survival and motion model")
    likelihood: LikelihoodParams = part(LikelihoodParams, "p_M and the Gaussian g(z|x)")
    clutter: ClutterParams = part(ClutterParams, "clutter intensity κ(z)")
    birth: BirthParams = part(BirthParams, "newborn particles")
    resampling: ResamplingParams = part(ResamplingParams, "particle count after the update")
    gating: GatingParams = part(GatingParams, "where g(z|x) is evaluated (speed, not model)")
    score: ScoreParams = part(ScoreParams, "detection scores in the update (not in paper)")

    @classmethod
    def of(cls, **options) -> "PHDParams":
        """Defaults with some fields set by leaf name: ``PHDParams.of(p_miss=0.2, rho=500)``."""
        return with_options(cls(), options)


# ----------------------------------------------------------------------------- observation model

@lru_cache(maxsize=32)
def gate_threshold(confidence: float, dof: int = OBS_DIM) -> float:
    """Squared Mahalanobis radius of the ``confidence`` ellipsoid in ``dof`` dimensions."""
    # scipy.stats.chi2.ppf's own formula (the same float); importing scipy.stats cost ~1.4 s
    # of CPU at every start-up, scipy.special is loaded anyway
    from scipy.special import gammaincinv

    return float(2.0 * gammaincinv(dof / 2.0, confidence))


def as_observations(Z) -> np.ndarray:
    """Check and return detections as (N_z, 4) float64 ``(y1, y2, w, h)``; accepts a
    :class:`~pfscope.trackers.types.Detections` (its ``observations()``) or an array."""
    if hasattr(Z, "observations"):
        Z = Z.observations()
    z = np.asarray(Z, dtype=np.float64)
    if z.size == 0:
        return np.zeros((0, OBS_DIM))
    if z.ndim != 2 or z.shape[1] != OBS_DIM:
        raise ValueError(f"observations: expected shape (N, 4) (y1, y2, w, h), got {z.shape}")
    # ndarray methods, not np.all/np.any (the filter's step checks in its kernel pass instead,
    # observations_noise; not here: the warm-up's main process would compile that kernel
    # again, the first-run helper compiles it)
    if not np.isfinite(z).all():
        raise ValueError("observations: non-finite values")
    if (z[:, 2:4] <= 0).any():
        raise ValueError("observations: box width and height must be > 0")
    return z


def observations_noise(Z, lk: LikelihoodParams) -> tuple[np.ndarray,
                                                         tuple[np.ndarray, np.ndarray]]:
    """:func:`as_observations` (the same array and errors) and the detections' noise
    ``(σ, log σ)``, both (N_z, 4): :func:`obs_std` of their sizes and numpy's ``log`` of it,
    the checks and the stds of a float64 (N_z, 4) array in one kernel pass
    (:func:`._kernels.observation_noise`): what :meth:`PHDFilter.step` needs of ``Z``.  The
    kernels that read the noise sum a row's logs themselves (``Σ_d log σ_d`` of
    :func:`detection_noise`, numpy's sum: :func:`._kernels._log_norms`)."""
    if type(Z) is not np.ndarray and hasattr(Z, "observations"):   # (no failed lookup on
        Z = Z.observations()                                        # an array: a raise)
    if not (type(Z) is np.ndarray and Z.dtype == np.float64 and Z.ndim == 2
            and Z.shape[1] == OBS_DIM and len(Z) and Z.flags.c_contiguous):
        Z = as_observations(Z)
        std = obs_std(Z[:, 2:4], lk)
        return Z, (std, np.log(std))
    code, std = _kernels.observation_noise(Z, lk.sigma_obs, lk.sigma_obs_min,
                                           lk.sigma_obs_pos_ratio)
    if code:
        as_observations(Z)              # raises its error
        raise AssertionError("observations_noise: the kernel's check and numpy's disagree")
    # log σ: numpy's log (not libm's: one ulp apart at times)
    return Z, (std, np.log(std))


def obs_std(sizes: np.ndarray, lk: LikelihoodParams = LikelihoodParams()) -> np.ndarray:
    """Observation-noise std ``(σ_y1, σ_y2, σ_w, σ_h)`` for boxes of ``sizes`` (..., 2) = (w, h):
    ``σ_w = max(0.15 w, 1)``, ``σ_h = max(0.15 h, 1)``, ``σ_y = σ_size / 2`` (maggio2007 §4)."""
    s = np.maximum(lk.sigma_obs * np.asarray(sizes, dtype=np.float64), lk.sigma_obs_min)
    out = np.empty(s.shape[:-1] + (2 * s.shape[-1],))
    np.multiply(lk.sigma_obs_pos_ratio, s, out=out[..., :s.shape[-1]])
    out[..., s.shape[-1]:] = s
    return out


def detection_noise(Z: np.ndarray, lk: LikelihoodParams) -> tuple[np.ndarray, np.ndarray]:
    """The observation-noise stds of the detections ``Z`` (N_z, 4) (:func:`obs_std` of their
    sizes) and ``Σ_d log σ_d`` per detection: computed once a frame, read by M(z), the
    newborn weights and the update."""
    std = obs_std(Z[:, 2:4], lk)
    return std, np.log(std).sum(-1)


def _mahalanobis2(states: np.ndarray, Z: np.ndarray, std: np.ndarray) -> np.ndarray:
    """(N, N_z) squared distances of particles' observed part to each z, per-z (N_z, 4) or
    per-pair (N, N_z, 4) std."""
    q = states[:, None, OBS_COLS] - Z[None, :, :]
    q /= std if std.ndim == 3 else std[None]
    return np.einsum("ijk,ijk->ij", q, q)


def log_likelihood(states: np.ndarray, Z: np.ndarray,
                   lk: LikelihoodParams = LikelihoodParams()) -> np.ndarray:
    """``log g(z | x)`` as an (N, N_z) matrix: Gaussian on (y1, y2, w, h) (maggio2007 §2, §4)."""
    if lk.obs_std_source == "detection":
        std = obs_std(Z[:, 2:4], lk)                            # (N_z, 4)
        log_norm = np.log(std).sum(-1)[None, :]
    else:
        std = np.broadcast_to(obs_std(states[:, None, 4:6], lk),
                              (len(states), len(Z), OBS_DIM))   # (N, N_z, 4)
        log_norm = np.log(std).sum(-1)
    d2 = _mahalanobis2(states, Z, std)
    return -0.5 * d2 - log_norm - 0.5 * OBS_DIM * math.log(2 * math.pi)


def log_likelihood_pairs(states: np.ndarray, Z: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                         lk: LikelihoodParams = LikelihoodParams()) -> np.ndarray:
    """``log g(z_cols | x_rows)`` (P,) on pairs only: the same Gaussian as
    :func:`log_likelihood` (``log_likelihood(states, Z, lk)[rows, cols]`` up to round-off)."""
    rows = np.asarray(rows, dtype=np.intp)
    cols = np.asarray(cols, dtype=np.intp)
    q = states[np.ix_(rows, OBS_COLS)]                           # (P, 4), one gather
    if lk.obs_std_source == "detection":
        std_z = obs_std(Z[:, 2:4], lk)                          # (N_z, 4)
        log_norm = np.log(std_z).sum(-1)[cols]
        q -= Z[cols]
        q /= std_z[cols]
    else:
        std = obs_std(q[:, 2:4], lk)                            # (P, 4), the particle's size
        log_norm = np.log(std).sum(-1)
        q -= Z[cols]
        q /= std
    d2 = np.einsum("ij,ij->i", q, q)
    return -0.5 * d2 - log_norm - 0.5 * OBS_DIM * math.log(2 * math.pi)


class Likelihood(Protocol):
    """The single-target likelihood g(z|x) the PHD update uses (maggio2007 eq. (5), feng2015
    eqs. (11)–(12)).  ``frame`` gives image-based likelihoods (feng2015's DBN score) the
    pixels; the Gaussian ignores it.  ``states`` (N, 6) particles, ``Z`` (N_z, 4) detections
    ``(y1, y2, w, h)``.

    - ``log_g(states, Z, frame) -> (N, N_z)`` (required): the log-likelihood matrix, ``-inf``
      where a particle cannot have produced z.  It must be elementwise in (x, z): the filter
      may call it on a subset of the particles and of the detections.
    - ``log_g_pairs(states, Z, rows, cols, frame) -> (P,)`` (optional, :class:`PairLikelihood`):
      ``log g(Z[cols[p]] | states[rows[p]])`` on candidate pairs only; ``rows``/``cols`` (P,)
      intp index ``states``/``Z``.  The filter asks only for the pairs inside the update gate
      (:mod:`.gating`: the observation-noise ellipsoid of each z, at ``gate_tail``) and takes
      g = 0 on every other pair, so the cost stays linear in the number of targets.

    The filter uses ``log_g_pairs`` when present; otherwise it evaluates ``log_g`` on blocks
    (particles near a group of detections × those detections, at most ``pair_budget`` entries
    each) and keeps the same gated pairs — same results, bounded memory, more work."""

    def log_g(self, states: np.ndarray, Z: np.ndarray, frame: Optional[Frame]) -> np.ndarray: ...


class PairLikelihood(Likelihood, Protocol):
    """A :class:`Likelihood` that also evaluates g on candidate pairs (``log_g_pairs``)."""

    def log_g_pairs(self, states: np.ndarray, Z: np.ndarray, rows: np.ndarray,
                    cols: np.ndarray, frame: Optional[Frame]) -> np.ndarray: ...


@dataclass(frozen=True)
class GaussianLikelihood:
    """maggio2007's g(z|x): a Gaussian on (y1, y2, w, h), stds proportional to the box size."""

    params: LikelihoodParams = LikelihoodParams()

    def log_g(self, states: np.ndarray, Z: np.ndarray, frame: Optional[Frame] = None) -> np.ndarray:
        return log_likelihood(states, Z, self.params)

    def log_g_pairs(self, states: np.ndarray, Z: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                    frame: Optional[Frame] = None) -> np.ndarray:
        return log_likelihood_pairs(states, Z, rows, cols, self.params)


def log_clutter_density(Z: np.ndarray, cl: ClutterParams = ClutterParams(),
                        lk: LikelihoodParams = LikelihoodParams()) -> np.ndarray:
    """``log κ(z)`` (N_z,): ``clutter_rate`` points spread over the ``clutter_gate`` confidence
    ellipsoid of the observation noise around z (reading of maggio2007 §4, module docstring)."""
    if cl.clutter_rate > 0:
        return math.log(cl.clutter_rate) - log_gate_volume(Z, cl, lk)
    return np.full(len(Z), -np.inf)


def log_gate_volume(Z: np.ndarray, cl: ClutterParams, lk: LikelihoodParams,
                    std: Optional[np.ndarray] = None) -> np.ndarray:
    """``log V(z)`` (N_z,): the volume of the ``clutter_gate`` confidence ellipsoid of the
    observation noise around each z (:func:`log_clutter_density` is ``log clutter_rate − log
    V``; the learnt clutter's parts share one per frame, :meth:`SceneModel.log_kappa`).
    ``std``: ``obs_std(Z[:, 2:4], lk)`` when the caller has it."""
    if std is None:
        std = obs_std(Z[:, 2:4], lk)
    return log_gate_volume0(cl) + np.log(std).sum(-1)


def log_gate_volume0(cl: ClutterParams) -> float:
    """:func:`log_gate_volume` without its ``Σ_d log σ_d``: the log volume of the
    ``clutter_gate`` ellipsoid of unit stds."""
    r2 = gate_threshold(cl.clutter_gate, OBS_DIM)
    d = OBS_DIM
    log_unit_ball = 0.5 * d * math.log(math.pi) - math.lgamma(0.5 * d + 1)
    return log_unit_ball + 0.5 * d * math.log(r2)


# ----------------------------------------------------------------------------- scene clutter

class SceneModel:
    """Online estimates behind ``clutter_model='scene'`` and ``score_model='gaussian'`` (module
    docstring, "Scene clutter"), one instance per filter (deterministic: no randomness).

    - clutter rate λ: exponential average of ``Σ_z κ/(κ + C)`` -- the detections of the frame
      the update did not give to a target (EM for the rate of the Poisson clutter), starting
      at ``clutter_rate``;
    - spatial density: uniform over the image (``frame`` size; without a frame, the bounding
      box of every detection seen so far), plus ``near_rate`` points around each detection
      spread as in ``'gate'`` (false boxes near people: duplicates, misplaced boxes), with
      ``near_learn`` estimated as the mean number of other detections of the frame inside a
      detection's ``clutter_gate`` ellipsoid (exponential average from ``near_rate``);
    - size density: log-normal in (w, h), mean and covariance of ``log(w, h)`` of all
      detections (exponential average);
    - scores: two Gaussians with one pooled variance, weighted by ``C/(κ + C)`` (target) and
      ``κ/(κ + C)`` (clutter); the ratio is used only while the target mean is the higher.

    Averages are over about ``clutter_memory`` frames."""

    _LOG_SIZE_FLOOR = 0.05 ** 2    # log-size variance floor (5 % of the size)
    #: the practical settings' log_kappa / learn in one kernel call each (False: the calls
    #: one by one, the reference the tests compare with)
    fused = True

    def __init__(self, params: "PHDParams"):
        self.cl, self.sp = params.clutter, params.score
        self.lk = params.likelihood
        self.rate = float(self.cl.clutter_rate)
        self.near = float(self.cl.near_rate)
        self.frames = 0
        self.size_frames = 0
        self.size_m1 = np.zeros(2)
        self.size_m2 = np.zeros((2, 2))
        self.extent: Optional[np.ndarray] = None       # (x0, y0, x1, y1) of all detections
        self.score_sums: Optional[np.ndarray] = None   # (2, 3): class (target, clutter) × S0..S2
        self.score_floor = 1e-12
        # persistence label of this frame's detections for the score fit (ScoreParams)
        self.chains = Chains()
        self._persist: Optional[np.ndarray] = None
        self._chained: Optional[np.ndarray] = None       # 'learn': continues a chain
        #: 'learn' with spot_places: per detection of the last learnt frame, P(its chain up to
        #: it is clutter)
        self._chain_clutter: Optional[np.ndarray] = None
        self.persist_sums: Optional[np.ndarray] = None   # as score_sums, labelled by persistence
        # 'learn': the repeated-in-place part of κ (.clutter), this frame's parts for learn()
        learn = self.cl.clutter_model == "learn"
        self.place = PlaceClutter(self.cl, self.lk) if learn else None
        self.people = NearClutter(self.cl, self.lk) if learn else None
        self.dups = DuplicateBoxes(self.cl, self.lk) if learn else None
        self._parts: Optional[tuple] = None
        #: what :meth:`_log_kappa_fused` leaves for :meth:`_learn_fused` (None: the calls one
        #: by one)
        self._fused: Optional[tuple] = None
        #: the birth gate's r² (:func:`birth`'s M(z)): where it is the clutter gate's, κ_n's
        #: M'(z) and the birth's M(z) come from one pass (:meth:`_near_mass`)
        self._birth_r2 = gate_threshold(params.birth.gate, OBS_DIM)
        self._birth_mass: Optional[tuple] = None
        #: :func:`.clutter.scene_frame`'s scalars (written each frame), the clutter gate's
        #: log volume of unit stds with the settings it is for
        self._par = np.zeros(N_SCENE_PAR)
        self._fset: Optional[tuple] = None     # (_fused_settings)
        #: _weights_exposure's two exps, and the one weight as a read-only view of them
        b = np.empty(2)
        v = b[:1]
        v.setflags(write=False)         # (the weights property's type: one specialisation)
        self._wexp = (b, v)
        self._lpar = np.zeros(_N_L)
        self._lset: Optional[tuple] = None     # (cl, r2, dup r2) _lpar's settings' scalars are of

    def set_likelihood(self, lk: LikelihoodParams) -> None:
        """New observation-noise widths for the clutter volumes (PHDFilter.set_params)."""
        self.lk = lk
        for part in (self.place, self.people, self.dups):
            if part is not None:
                part.lk = lk

    def structured(self) -> float:
        """'learn': the share of the clutter that is structured (near people or repeated in
        place) rather than random, from the EM averages (.clutter)."""
        rep = self.people.count() + self.place.count()
        return rep / (rep + self.rate) if rep + self.rate > 0 else 0.0

    @property
    def scene_clutter(self) -> bool:
        return self.cl.clutter_model in ("scene", "learn")

    @property
    def uses_scores(self) -> bool:
        return self.sp.score_model == "gaussian"

    def _image_area(self, frame: Optional[Frame]) -> float:
        """The frame's pixel area when it has an image, else 0 (the density takes the area of
        the detections' extent then: :func:`.clutter.scene_density`)."""
        im = None if frame is None else getattr(frame, "image", None)
        if im is None:
            return 0.0
        sh = np.shape(im)               # (frame.width * frame.height: its shape's)
        return float(int(sh[1]) * int(sh[0])) if len(sh) >= 2 and np.size(im) else 0.0

    def log_kappa(self, Z: np.ndarray, scores: Optional[np.ndarray],
                  frame: Optional[Frame], predicted: Optional[ParticleSet] = None,
                  std: Optional[np.ndarray] = None) -> tuple[np.ndarray, np.ndarray]:
        """``log κ(z)`` (N_z,) of this frame's detections: the one the newborn weigh against
        (without the scores; with ``spot_places``, also without the place memory), then the
        update's (with the scores).  ``std``: the detections' :func:`obs_std` under this
        model's likelihood when the caller has them (:func:`detection_noise`)."""
        log_birth = None
        self._fused = None
        persist = self.uses_scores and self.sp.persist_frames > 0
        if persist or self.place is not None:
            # a no-op when the frame was linked already (PHD-MT shares its scene learner's)
            self.chains.observe(Z, None if frame is None else frame.index)
            if self.fused and self.place is not None:
                done = self._log_kappa_fused(Z, scores, frame, predicted, std, persist)
                if done is not None:
                    return done
        if self.scene_clutter:
            # the detections' observation stds, once a frame for every part that reads them
            if std is None:
                std = obs_std(Z[:, 2:4], self.lk)
            n_near = n_dup = std_wide = None
            if self.place is not None:
                # the parts read this frame's settings (dups.on below among them)
                self.place.cl = self.people.cl = self.dups.cl = self.cl
                # ... and the stds times NEAR_SCALE, for the near-people and duplicate terms
                std_wide = self.people.wide_std_of(std)
            if self.cl.near_learn and len(Z):
                if self.place is not None and self.cl.learn_update == "model" \
                        and self.dups.on(Z):
                    # the neighbour count and the duplicate term's (its gates times
                    # NEAR_SCALE) in one pass
                    n_near, n_dup = neighbour_counts(
                        Z, gate_threshold(self.cl.clutter_gate, OBS_DIM), std, std_wide)
                a = 1.0 / min(self.frames + 5, self.cl.clutter_memory)
                # (the counts' mean as np.mean's float: their sum is exact, one division)
                self.near = (1 - a) * self.near + a * (
                    self._neighbours(Z, std) if n_near is None
                    else int(n_near.sum()) / len(n_near))
            if self.extent is None and len(Z):
                self.extent = _no_extent()
            # the size moments, the extent, log κ_u (with near_rate points spread as the 'gate'
            # model when > 0) and the clutter gates' log V(z) (log V is −log of one clutter
            # point spread as the 'gate' model, log_gate_volume) in one pass: scene_density's
            # arguments (with 'learn', scene_terms below takes them)
            a = 1.0 / min(self.size_frames + 1, self.cl.clutter_memory)
            log_rate = math.log(self.rate) if self.rate > 0 else -math.inf
            density = (Z, std, self.size_m1, self.size_m2,
                       _no_extent() if self.extent is None else self.extent, a, len(Z) > 0,
                       log_rate, self._image_area(frame), log_gate_volume0(self.cl),
                       self._LOG_SIZE_FLOOR, self.near)
            if self.place is None:
                log_kappa, log_v = scene_density(*density)
                if len(Z):
                    self.size_frames += 1
            else:
                model = self.cl.learn_update == "model"
                # a detection that continues a chain of mutually nearest detections is a
                # person's or a spot's, not a box beside a person (those do not chain): κ_n
                # is 0 there, so it takes no share of it in the EM (the update alike with
                # learn_update 'model')
                self._chained = self.chains.length >= 1
                m = self._near_mass(Z, predicted, std, std_wide)
                # a second box on a person already boxed, which a Poisson κ cannot express:
                # the duplicate term (.clutter.DuplicateBoxes) joins the mixture ('model')
                n = self.dups.counts(Z, std_wide, n_dup) if model else None
                # scene_density, the place memory's sums in each detection's gate
                # (PlaceClutter._weight_in_gates) and the parts of κ (kappa_terms) in one call
                place = self.place
                log_kappa, log_v, log_rep, log_near, log_dup, shadow, no_place = scene_terms(
                    density, place.mem_z, place.mem_w, place.mem_e,
                    gate_threshold(self.cl.clutter_gate, OBS_DIM), place.beta,
                    None if m is None else (m, self.people.nu, self._chained),
                    None if n is None else (n, self.dups.q))
                if len(Z):
                    self.size_frames += 1
                if model:
                    log_used = shadow
                else:
                    log_used = np.logaddexp(log_kappa,
                                            self.place.log_gate(Z, self.structured(), log_v))
                self._parts = (Z, std, log_rep, log_near, log_dup, shadow, log_used)
                if self.cl.spot_places and model:
                    # a person appears no more often where clutter repeats: the newborn
                    # weigh against κ without the place memory (birth_odds, log_birth_weight)
                    log_birth = no_place
                log_kappa = log_used
        else:
            log_kappa = log_clutter_density(Z, self.cl, self.lk)
        if persist:
            self._persist = self.chains.length >= self.sp.persist_frames
        birth = log_kappa if log_birth is None else log_birth
        if self.uses_scores and scores is not None and len(Z):
            return birth, log_kappa - self.log_score_ratio(scores)
        return birth, log_kappa

    def _log_kappa_fused(self, Z: np.ndarray, scores: Optional[np.ndarray],
                         frame: Optional[Frame], predicted: Optional[ParticleSet],
                         std: Optional[np.ndarray], persist: bool) -> Optional[tuple]:
        """:meth:`log_kappa` after the chains in one kernel call (:func:`.clutter.scene_frame`)
        where the settings are the ``practical`` preset's (``learn`` clutter, ``learn_update``
        'model', ``near_learn``, the duplicate term on, the birth gate the clutter gate) and
        the frame has 1 <= N_z, N_z² < BRUTE_PAIRS detections (float64, C-contiguous) and
        predicted particles: the same floats and the same state after it as the calls one by
        one (the reference, ``fused`` False).  None (nothing done) elsewhere."""
        cl = self.cl
        fs = self._fset
        if fs is None or fs[0] is not cl or fs[1] is not self.sp:
            fs = self._fset = self._fused_settings()
        nz = len(Z)
        if not (fs[2] and nz >= 1 and nz * nz < BRUTE_PAIRS
                and predicted is not None and len(predicted)
                and type(Z) is np.ndarray and Z.dtype == np.float64 and Z.ndim == 2
                and Z.shape[1] == OBS_DIM and Z.flags.c_contiguous
                and len(self.chains.length) == nz):
            return None
        r2 = fs[3]
        if std is None:
            std = obs_std(Z[:, 2:4], self.lk)
        if not (type(std) is np.ndarray and std.dtype == np.float64 and std.flags.c_contiguous):
            return None
        ratio = self.uses_scores and scores is not None
        if ratio:
            scores = np.ascontiguousarray(scores, dtype=np.float64)
            if scores.shape != (nz,):
                return None
            self._score_init(scores)
        place, people, dups = self.place, self.people, self.dups
        place.cl = people.cl = dups.cl = cl
        if self.extent is None:
            self.extent = _no_extent()
        w, exposure = _weights_exposure(predicted, self._wexp)
        people.record(predicted, exposure)
        # scene_frame's scalars, written into this model's own array (the same floats as
        # np.array of them; those of the settings alone written by _fused_settings)
        par = self._par
        par[P_A_NEAR] = 1.0 / min(self.frames + 5, cl.clutter_memory)
        par[P_NEAR] = self.near
        par[P_A] = 1.0 / min(self.size_frames + 1, cl.clutter_memory)
        par[P_LOG_RATE] = math.log(self.rate) if self.rate > 0 else -math.inf
        par[P_AREA] = self._image_area(frame)
        par[P_N0_BETA] = PRIOR_FRAMES * place.beta
        par[P_NU] = people.nu
        par[P_Q] = dups.q
        par[P_RATIO] = 1.0 if ratio else 0.0
        par[P_SCORE_FLOOR] = self.score_floor
        par[P_USE_PSUMS] = 0.0 if self.persist_sums is None else 1.0
        ss = self.score_sums if ratio else _NO_SUMS
        pos_ext = predicted.extent()        # (predict's: the grid skips a pass over the rows)
        code, near, wide, chained, persist_now, n_dup, m, grid, m_near, out, final = scene_frame(
            predicted.states, w, Z, std, self.chains.length,
            scores if ratio else _NO_SCORES, par, self.size_m1, self.size_m2, self.extent,
            place.mem_z, place.mem_w, place.mem_e, ss,
            self.persist_sums if ratio and self.persist_sums is not None else ss,
            _NO_EXT if pos_ext is None else pos_ext)
        if not code:
            raise ValueError("mass_near: non-finite particle positions")
        self.near = near
        self._chained = chained
        self._birth_mass = (predicted, Z, std, r2, m, grid)
        # (DuplicateBoxes.counts: off for a lone detection, whose count 0 gives the same
        # log κ_d = -inf as the term left out)
        dups._pairs = (Z, wide, r2, n_dup) if nz >= 2 else None
        self.size_frames += 1
        if code == 2:
            # gate_sums' one-pass grid declined: its GridIndex path and kappa_terms, as
            # scene_terms does
            S, E, _ = gate_sums(place.mem_z, Z, r2, std, place.mem_w, place.mem_e)
            _kappa_terms(out[1], S, E, PRIOR_FRAMES * place.beta, m_near,
                         people.nu, chained, n_dup, dups.q, out[0], out[2:])
            final = out[5] - (self.log_score_ratio(scores) if ratio else 0.0)
        shadow = out[5]
        self._parts = (Z, std, out[2], out[3], out[4], shadow, shadow)
        self._fused = (out, wide, n_dup, r2)
        if persist:
            self._persist = persist_now
        birth = out[6] if cl.spot_places else shadow
        return birth, (final if ratio else shadow)

    def _fused_settings(self) -> tuple:
        """``(cl, sp, ok, r2)`` of this model's settings (kept while they are the same objects:
        :meth:`_log_kappa_fused`): ``ok`` whether they are the fused path's (``learn_update``
        'model', ``near_learn``, the duplicate term on, the birth gate the clutter gate), r2
        the clutter gate's; writes :func:`.clutter.scene_frame`'s scalars of the settings
        alone into ``_par``."""
        cl, sp = self.cl, self.sp
        r2 = gate_threshold(cl.clutter_gate, OBS_DIM)
        ok = (cl.learn_update == "model" and bool(cl.near_learn) and cl.duplicate_prior > 0
              and r2 == self._birth_r2)
        par = self._par
        par[P_R2] = r2
        par[P_SEE] = 1.0
        par[P_LOG_V0] = log_gate_volume0(cl)
        par[P_FLOOR] = self._LOG_SIZE_FLOOR
        par[P_CLIP] = sp.max_log_ratio
        par[P_PERSIST] = sp.persist_frames
        return cl, sp, ok, r2

    def _near_mass(self, Z: np.ndarray, predicted: Optional[ParticleSet], std: np.ndarray,
                   std_wide: Optional[np.ndarray]) -> Optional[np.ndarray]:
        """κ_n's ``M'(z)`` (:meth:`.clutter.NearClutter.mass`, 0 where chained).  Where the birth
        gate is the clutter gate (the presets), the birth's M(z) of this frame comes from the
        same pass over the predicted particles (:func:`mass_near_two`) and waits for
        :func:`birth` (:meth:`take_birth_mass`)."""
        people = self.people
        if predicted is None or not len(Z) or not len(predicted) or std_wide is None:
            return people.mass(Z, predicted, self._chained, std_wide)
        r2 = gate_threshold(self.cl.clutter_gate, OBS_DIM)
        if r2 != self._birth_r2:
            return people.mass(Z, predicted, self._chained, std_wide)
        people.record(predicted)
        near, self._birth_mass = mass_near_two(predicted, Z, std, r2, std_wide, self._chained)
        return near

    def take_birth_mass(self) -> Optional[tuple]:
        """The birth's M(z) computed by this frame's :meth:`log_kappa` (:meth:`_near_mass`),
        once, for :func:`birth`'s ``ahead`` (None when it made none)."""
        ahead, self._birth_mass = self._birth_mass, None
        return ahead

    def _neighbours(self, Z: np.ndarray, std: Optional[np.ndarray] = None) -> float:
        """Mean number of other detections inside each detection's ``clutter_gate`` ellipsoid
        (grid-indexed pairs, :func:`~.gating.gate_pairs`); ``std``: the detections'
        observation stds when the caller has them."""
        return float(neighbours(Z, self.cl, self.lk, std=std).mean())

    def log_score_ratio(self, scores: np.ndarray) -> np.ndarray:
        """``log p(s|target) − log p(s|clutter)``, clipped to ±max_log_ratio: the fit on the
        mass, or the fit on persistence when that one separates the classes more
        (:class:`ScoreParams`)."""
        s = np.asarray(scores, dtype=np.float64)
        best = self._score_fit(s)
        # used only while targets score higher than clutter on average (a higher score means a
        # more likely target, the detector's convention); otherwise the scores carry no
        # information yet (e.g. no target seen) and the ratio is 1.
        if best is None:
            return np.zeros(len(s))
        _, slope, mid = best
        c = self.sp.max_log_ratio
        return np.clip(slope * (s - mid), -c, c)

    def _score_fit(self, s: np.ndarray) -> Optional[tuple[float, float, float]]:
        """:meth:`log_score_ratio`'s fit ``(d'², slope, midpoint)`` or None (the sums set up
        from the scores ``s`` (float64) on the first call)."""
        self._score_init(s)
        best = self._two_class_fit(self.score_sums)
        if self.persist_sums is not None:
            other = self._two_class_fit(self.persist_sums)
            if best is None or (other is not None and other[0] > best[0]):
                best = other
        return best

    def _score_init(self, s: np.ndarray) -> None:
        """The score sums' prior from the first frame's scores ``s`` (float64)."""
        if self.score_sums is None:
            mu, var = float(s.mean()), float(s.var())
            self.score_floor = max(1e-12, 1e-3 * var)
            var = max(var, self.score_floor)
            n0 = self.sp.score_prior
            self.score_sums = np.array([[n0, n0 * mu, n0 * (mu * mu + var)]] * 2)
            if self.sp.persist_frames > 0:
                self.persist_sums = self.score_sums.copy()

    def _two_class_fit(self, S: np.ndarray) -> Optional[tuple[float, float, float]]:
        """Two Gaussians of one pooled within-class variance from the sums ``S`` (class ×
        S0..S2): ``(d'², slope, midpoint)`` of the log-ratio ``slope · (s − midpoint)`` (linear
        in s), d' = the separation of the means in within-class stds; None unless the target
        mean is the higher."""
        # on the six float64 scalars: the (2, 3) array's ~10 numpy calls were most of the cost
        # (the same floats: x ** 2 is x * x there, and a sum of two terms is a + b)
        a0, a1, a2, b0, b1, b2 = S.reshape(-1)
        m0, m1 = a1 / a0, b1 / b0
        if not m0 > m1:
            return None
        var = max(((a2 - a1 * a1 / a0) + (b2 - b1 * b1 / b0)) / (a0 + b0), self.score_floor)
        gap = m0 - m1
        return gap * gap / var, gap / var, 0.5 * (m0 + m1)

    def learn(self, scores: Optional[np.ndarray], won: np.ndarray) -> None:
        """After the update: ``won`` (N_z,) = C/(κ + C), each detection's target share."""
        fused, self._fused = self._fused, None
        if fused is not None and self.fused and self._parts is not None \
                and self._learn_fused(scores, won, fused):
            return
        a = 1.0 / min(self.frames + 5, self.cl.clutter_memory)
        if self.place is not None and self._parts is not None:
            Z, std, log_rep, log_near, log_dup, total, log_used = self._parts
            spot = self.cl.spot_places and self.cl.learn_update == "model"
            # the clutter shares and their split between the parts (in one pass)
            sums = np.empty(3)
            out, random = learn_shares(won, log_used, total, (log_rep, log_near, log_dup),
                                       self.chains.prev_link if spot else None,
                                       self._chain_clutter if spot else None, sums)
            self.rate = (1 - a) * self.rate + a * random
            # a duplicate box is the person's, not a place's: it leaves no place memory;
            # with spot_places a place's memory counts a detection that continues a chain by
            # the probability that the chain so far is clutter: a spot's firings win no mass
            # and its chain stays clutter, a newcomer's chain stops being clutter as soon as
            # its detections win mass (the chain prior: P(the chain a detection continues is
            # clutter), the last learnt frame's value at its link, 1 where it continues none)
            if spot:
                self._chain_clutter = out[4]
            # (the sums of out[2], out[3] from the same pass: np.sum's floats)
            self.place.learn(Z, out[1], out[2], a, std, float(sums[1]))
            self.people.learn(out[3], a, float(sums[2]))
            if self.cl.learn_update == "model":
                self.dups.learn(won, a)
            self._parts = None
        elif self.scene_clutter:
            self.rate = (1 - a) * self.rate + a * float(np.sum(1.0 - won))
        self.frames += 1
        if self.uses_scores and scores is not None and self.score_sums is not None:
            s = np.ascontiguousarray(scores, dtype=np.float64)
            won = np.ascontiguousarray(won, dtype=np.float64)
            d = 1.0 - 1.0 / self.cl.clutter_memory
            # the weighted S0..S2 of the scores per class (won, 1 − won), and labelled by
            # persistence, faded and added in place (one pass: _score_sums)
            persist = self.persist_sums is not None and self._persist is not None \
                and len(self._persist) == len(s)
            _score_sums(won, s, self._persist if persist else _NO_PERSIST, persist, d,
                        self.score_sums, self.persist_sums if persist else self.score_sums)


    def _learn_fused(self, scores: Optional[np.ndarray], won: np.ndarray,
                     fused: tuple) -> bool:
        """:meth:`learn` after :meth:`_log_kappa_fused` in one kernel call (:func:`scene_learn`):
        the same floats and state as the calls one by one.  False (nothing done) where the
        frame does not fit (``won`` or the scores not of the frame's length)."""
        out, wide, n_dup, r2_dup = fused
        cl, place, people, dups = self.cl, self.place, self.people, self.dups
        Z, std = self._parts[0], self._parts[1]
        nz = len(Z)
        won = np.ascontiguousarray(won, dtype=np.float64)
        if won.shape != (nz,) or cl.learn_update != "model" or cl.duplicate_prior <= 0:
            return False
        use_s = self.uses_scores and scores is not None and self.score_sums is not None
        s = _NO_SCORES
        use_p = False
        if use_s:
            s = np.ascontiguousarray(scores, dtype=np.float64)
            if s.shape != (nz,):
                return False
            use_p = self.persist_sums is not None and self._persist is not None \
                and len(self._persist) == nz
        spot = cl.spot_places
        prev_link, chain_c = self.chains.prev_link, self._chain_clutter
        use_chain = (spot and prev_link is not None and chain_c is not None
                     and len(prev_link) == nz and len(chain_c) > 0)
        fs = self._fset
        lk, r2, S, exposure = place._sums_of(fs[3] if fs is not None and fs[0] is cl else None)
        a = 1.0 / min(self.frames + 5, cl.clutter_memory)
        par = self._lpar                    # (scene_learn's scalars, as _log_kappa_fused's)
        lset = self._lset
        if lset is None or lset[0] is not cl or lset[1] != r2 or lset[2] != r2_dup:
            # those of the settings alone: written again when they change
            par[_L_FADE] = place.fade
            par[_L_MIN_W] = MIN_WEIGHT
            par[_L_R2] = r2
            par[_L_BUDGET] = INCREMENT_PAIRS
            par[_L_DUP_R2] = r2_dup
            par[_L_D] = 1.0 - 1.0 / cl.clutter_memory
            self._lset = (cl, r2, r2_dup)
        par[_L_DUP] = 0.0 if dups._pairs is None else 1.0
        par[_L_SCORES] = 1.0 if use_s else 0.0
        par[_L_PERSIST] = 1.0 if use_p else 0.0
        sh, ssum, mem, num, den = scene_learn(
            won, out, prev_link if use_chain else _NO_I, chain_c if use_chain else _NO_F,
            place.mem_z, place.mem_s, place.mem_w, place.mem_e, S, Z, std, wide, n_dup, s,
            self._persist if use_p else _NO_PERSIST,
            self.score_sums if use_s else _NO_SUMS,
            self.persist_sums if use_p else _NO_SUMS, par)
        self.rate = (1 - a) * self.rate + a * float(ssum[0])
        if spot:
            self._chain_clutter = sh[4]
        place.em_step(a, float(ssum[1]), exposure)
        place.keep_memory(lk, r2, mem)
        people.learn(None, a, float(ssum[2]))       # (the near shares' sum is all it reads)
        dups.em_step(a, num, den)
        self._parts = None
        self.frames += 1
        return True


def _weights_of(ps: ParticleSet) -> np.ndarray:
    """``ps.weights`` for :func:`.clutter.scene_frame`, or, where the set's weights are known
    equal and not made yet, their one value ``np.exp(lw[:1])`` (1,) (the property's float; the
    kernel writes the (N,) array itself)."""
    if len(ps) > 1 and ps.is_known_equal() and not ps.made("weights"):
        w = np.exp(ps.log_weights[:1])
        w.setflags(write=False)         # (the property's type: one specialisation)
        return w
    return ps.weights


def _weights_exposure(ps: ParticleSet, buf: Optional[tuple] = None) -> tuple:
    """``(_weights_of(ps), exposure)``: where the set's weights are known equal and neither
    they nor its mass are made yet, their one value and :meth:`.clutter.NearClutter.record`'s
    exposure (the set's mass) from ONE np.exp of the two arguments ``(lw_0, log n + lw_0)``
    (numpy's exp of an element does not depend on its neighbours or the array's length: the
    two calls' floats); else ``(_weights_of(ps), None)`` (record computes the exposure).
    ``buf``: ``(b, v)``, a (2,) float64 array and a read-only view of its first element,
    which the one value and the exposure are written into (``np.exp(b, b)``: the same floats,
    no arrays made), the caller's to keep until the next call."""
    n = len(ps)
    if n > 1 and not ps.made("weights", "mass", "log_mass") and ps.is_known_equal():
        lw0 = float(ps.log_weights[0])
        if math.isfinite(lw0):
            if buf is not None:
                b = buf[0]
                b[0] = lw0
                b[1] = _log_count(n) + lw0
                np.exp(b, b)
                return buf[1], float(b[1])
            e = np.exp(np.array((lw0, _log_count(n) + lw0)))
            w = e[:1]
            w.setflags(write=False)         # (the property's type: one specialisation)
            return w, float(e[1])
    return _weights_of(ps), None


_NO_PERSIST = np.zeros(0, dtype=np.bool_)
_NO_SUMS = np.zeros((2, 3))
_NO_SCORES = np.zeros(0)
_NO_EXT = np.zeros(0)


def _no_extent() -> np.ndarray:
    """An extent (x0, y0, x1, y1) before any detection: every box widens it."""
    return np.array([np.inf, np.inf, -np.inf, -np.inf])


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def _score_sums(won, s, persist, use_p, d, sums, psums):
    """``sums`` (2, 3) = ``d · sums`` + per class (weights ``won``, ``1 − won``) the weighted
    S0, S1, S2 of the scores ``s``; with ``use_p``, ``psums`` alike with the weights
    ``persist`` (N,) bool, ``~persist``."""
    n = s.shape[0]
    t = np.zeros(6)
    p = np.zeros(6)
    for j in range(n):
        x = s[j]
        xx = x * x
        w = won[j]
        v = 1.0 - w
        t[0] += w
        t[1] += w * x
        t[2] += w * xx
        t[3] += v
        t[4] += v * x
        t[5] += v * xx
        if use_p:
            k = 0 if persist[j] else 3
            p[k] += 1.0
            p[k + 1] += x
            p[k + 2] += xx
    for c in range(2):
        for m in range(3):
            sums[c, m] = d * sums[c, m] + t[3 * c + m]
    if use_p:
        for c in range(2):
            for m in range(3):
                psums[c, m] = d * psums[c, m] + p[3 * c + m]


#: :func:`scene_learn`'s scalars (``par``): their places
_L_FADE, _L_MIN_W, _L_R2, _L_BUDGET, _L_DUP, _L_DUP_R2, _L_SCORES, _L_PERSIST, _L_D = range(9)
_N_L = 9


@njit(cache=True, nogil=True, error_model="numpy", no_cfunc_wrapper=True)
def scene_learn(won, parts, prev_link, chain_clutter, mem_z, mem_s, mem_w, mem_e, mem_S, Z, std,
                wide, n_dup, scores, persist, sums, psums, par):
    """:meth:`SceneModel.learn`'s kernels in one call (``learn`` / ``model`` clutter, the
    frame :meth:`SceneModel._log_kappa_fused` made): :func:`.clutter._learn_shares` of
    ``parts`` (scene_frame's (7, N_z): its mixture row as κ_used and κ_s, the parts' rows),
    the place memory's step (:func:`.clutter._memory_step` of the memory, its S, ``Z``,
    ``std`` and the shares' place weights), with ``par[_L_DUP]`` the duplicate term's sums
    (:func:`.clutter._dup_sums_brute` of ``wide``, ``n_dup``) and with ``par[_L_SCORES]``
    :func:`_score_sums` into ``sums`` / ``psums`` (in place).  Returns ``(shares (5, N_z),
    share sums (3,), (z, s, w, e, S, exposure, ok), dup num, dup den)``: the same floats as
    the calls one by one."""
    nz = won.shape[0]
    sh = np.empty((5, nz))
    ssum = np.empty(3)
    _learn_shares(won, parts[5], parts[5], parts[2], parts[3], parts[4], prev_link,
                  chain_clutter, sh, ssum)
    mem = _memory_step(mem_z, mem_s, mem_w, mem_e, mem_S, Z, std, sh[1], par[_L_FADE],
                       par[_L_MIN_W], par[_L_R2], np.int64(par[_L_BUDGET]))
    num = den = 0.0
    if par[_L_DUP] != 0.0:
        num, den = _dup_sums_brute(won, Z, wide, par[_L_DUP_R2], n_dup, np.empty(nz),
                                   np.empty((2, nz)))
    if par[_L_SCORES] != 0.0:
        use_p = par[_L_PERSIST] != 0.0
        _score_sums(won, scores, persist, use_p, par[_L_D], sums, psums if use_p else sums)
    return sh, ssum, mem, num, den


# ----------------------------------------------------------------------------- the four stages

def predict(ps: ParticleSet, mp: MotionParams, rng: np.random.Generator,
            out: Optional[tuple[np.ndarray, np.ndarray]] = None) -> ParticleSet:
    """Persistent particles at k: ``x ~ f(.|x_{k-1})`` (q = f, so eq. (4) reduces to the
    survival factor, no spawning β), ``ω_{k|k-1} = e · ω_{k-1}`` (eqs. (1), (2), (4)).
    ``out`` = (states (M, 6), log-weights (M,)) with M >= N: written into (their first N rows),
    so the newborn can follow in the same arrays (:meth:`PHDFilter.step`)."""
    n = len(ps)
    S, L = out if out is not None else (None, np.empty(n))
    log_e = math.log(mp.p_survival) if mp.p_survival > 0 else -np.inf
    lw0 = ps.log_weights
    x = ps.states
    if n and S is not None and type(lw0) is np.ndarray and lw0.dtype == np.float64 \
            and L.dtype == np.float64 and len(L) >= n and x.dtype == np.float64 \
            and x.shape[1] == STATE_DIM and S.dtype == np.float64 and len(S) >= n \
            and S.shape[1] == STATE_DIM:
        # the filter's buffers (PHDFilter.step): motion.propagate's kernel call without its
        # checks and views (the same call: every argument of the same type)
        # (and the new positions' extent: the scene model's grid skips its own pass)
        ext = np.empty(5)
        _kernels.propagate_into(x, key_stream(rng), float(mp.sigma_v),
                                float(mp.sigma_size), float(mp.accel_to_position),
                                float(mp.min_size), S, lw0, float(log_e), L, ext)
        out = ParticleSet(S[:n], L[:n], ps.labels, ps.extra)
        out.known_extent(ext)
        if ps.is_known_equal():
            out.known_equal()
        return out
    elif n and type(lw0) is np.ndarray and lw0.dtype == np.float64 and L.dtype == np.float64:
        # ω · e written by the motion kernel's pass (numpy's add, the same floats)
        states = motion.propagate(ps.states, rng, sigma_v=mp.sigma_v, sigma_size=mp.sigma_size,
                                  accel_to_position=mp.accel_to_position,
                                  min_size=mp.min_size, out=S, log_weights=lw0, log_e=log_e,
                                  lw_out=L)
        lw = L[:n]
    else:
        states = motion.propagate(ps.states, rng, sigma_v=mp.sigma_v, sigma_size=mp.sigma_size,
                                  accel_to_position=mp.accel_to_position,
                                  min_size=mp.min_size, out=S)
        lw = np.add(lw0, log_e, out=L[:n])
    out = ParticleSet(states, lw, ps.labels, ps.extra)
    if ps.is_known_equal():       # equal weights times e: equal (ParticleSet.weights)
        out.known_equal()
    return out


@dataclass(frozen=True, init=False)
class BirthResult:
    """Newborn particles of one frame.

    particles: the J_k newborn; j_per_det (N_z,) int64 J_z; mass_near (N_z,) predicted mass
    M(z) inside the birth gate of each z; det_index (J_k,) int64 detection each newborn came from.
    """

    particles: ParticleSet
    j_per_det: np.ndarray
    mass_near: np.ndarray
    det_index: np.ndarray
    #: the grid M(z)'s kernel bucketed the predicted particles on (the update reuses it)
    grid: Optional[tuple] = field(default=None, repr=False, compare=False)

    def __init__(self, particles: ParticleSet, j_per_det: np.ndarray, mass_near: np.ndarray,
                 det_index: np.ndarray, grid: Optional[tuple] = None):
        # (a frozen dataclass's generated __init__ sets each field by object.__setattr__:
        # the instance dict directly costs a fraction; made every frame)
        d = self.__dict__
        d["particles"], d["j_per_det"], d["mass_near"] = particles, j_per_det, mass_near
        d["det_index"], d["grid"] = det_index, grid


def mass_near(predicted: ParticleSet, Z: np.ndarray, bp: BirthParams = BirthParams(),
              lk: LikelihoodParams = LikelihoodParams(),
              std_z: Optional[np.ndarray] = None,
              skip: Optional[np.ndarray] = None) -> np.ndarray:
    """M(z) (N_z,): predicted mass inside the ``gate`` confidence ellipsoid of the observation
    noise around each z (maggio2007 §2, "cumulative masses M(z_{k,j}) of the propagated
    particles that are inside the 99% confidence interval").  Only the particles near each z
    are looked at (a grid on the particles' positions, :func:`._kernels.mass_near_kernel`;
    the same float64 distances as the dense test); memory is O(N + N_z), with no pair budget
    to bound.  ``std_z``: ``obs_std(Z[:, 2:4], lk)`` when the caller has it.  ``skip`` (N_z,)
    bool: detections whose M(z) the caller does not need (0 there); the others get the very
    floats of the whole call (the same grid: its cells come from every detection's noise)."""
    if skip is None:
        return _mass_near(predicted, Z, bp, lk, std_z)[0]
    Z = np.asarray(Z, dtype=np.float64).reshape(-1, OBS_DIM)
    if len(predicted) == 0 or len(Z) == 0:
        return np.zeros(len(Z))
    if std_z is None:
        std_z = obs_std(Z[:, 2:4], lk)
    r2 = gate_threshold(bp.gate, OBS_DIM)
    # the very floats of mass_near_at's kernel on the same grid, without bucketing every
    # particle for a few detections (_kernels.mass_near_few), the cells and the skip in the
    # same call (_kernels.mass_near_skip)
    code, full = _kernels.mass_near_skip(predicted.states, predicted.weights, Z,
                                         np.ascontiguousarray(std_z, dtype=np.float64),
                                         np.ascontiguousarray(skip, dtype=np.bool_), float(r2))
    if not code:
        raise ValueError("mass_near: non-finite particle positions")
    return full


def _mass_near(predicted: ParticleSet, Z: np.ndarray, bp: BirthParams, lk: LikelihoodParams,
               std_z: Optional[np.ndarray],
               ahead: Optional[tuple] = None) -> tuple[np.ndarray, Optional[tuple]]:
    """:func:`mass_near` and the grid its kernel bucketed the predicted particles on (None
    when it made none), which the update reuses (:class:`GatedGaussian` ``persistent``).
    ``ahead``: what :func:`mass_near_two` computed ahead (``(predicted, Z, std_z, r², M(z),
    grid)``), used when it is for these very ``predicted``, ``Z`` and ``std_z`` objects and
    this gate."""
    if ahead is not None:
        if ahead[0] is predicted and ahead[1] is Z and ahead[2] is std_z \
                and ahead[3] == gate_threshold(bp.gate, OBS_DIM):
            return ahead[4], ahead[5]
    Z = np.asarray(Z, dtype=np.float64).reshape(-1, OBS_DIM)
    if len(predicted) == 0 or len(Z) == 0:
        return np.zeros(len(Z)), None
    if std_z is None:
        std_z = obs_std(Z[:, 2:4], lk)
    r2 = gate_threshold(bp.gate, OBS_DIM)
    return mass_near_at(predicted, Z, std_z, r2, _grid_cell(std_z, r2))


def mass_near_two(predicted: ParticleSet, Z: np.ndarray, std_z: np.ndarray, r2: float,
                  std_wide: np.ndarray, skip: np.ndarray) -> tuple[np.ndarray, tuple]:
    """:func:`mass_near` with the stds ``std_wide`` (``2 std_z``: κ_n's, :data:`.clutter.
    NEAR_SCALE`) and ``skip``, and the birth's M(z) with the stds ``std_z`` and its grid
    (``_mass_near(predicted, Z, bp, lk, std_z)`` where ``bp.gate`` gives ``r2``) as ``ahead``
    = ``(predicted, Z, std_z, r2, M(z), grid)`` for :func:`_mass_near`, returned as
    ``(near, ahead)``: one pass over the predicted particles
    (:func:`._kernels.mass_near_two`), the very floats of both calls.  ``predicted``: not
    empty; ``Z``: (N_z >= 1, 4) float64."""
    Zc = np.asarray(Z, dtype=np.float64).reshape(-1, OBS_DIM)
    cell = _grid_cell(std_z, r2)
    code, m, grid, near = _kernels.mass_near_two(
        predicted.states, predicted.weights, Zc, std_z, float(r2), cell[0], cell[1],
        np.ascontiguousarray(std_wide, dtype=np.float64),
        np.ascontiguousarray(skip, dtype=np.bool_))
    if not code:
        raise ValueError("mass_near: non-finite particle positions")
    return near, (predicted, Z, std_z, r2, m, grid)


def mass_near_at(predicted: ParticleSet, Z: np.ndarray, std_z: np.ndarray, r2: float,
                 cell: np.ndarray) -> tuple[np.ndarray, tuple]:
    """:func:`mass_near`'s kernel call on a grid of ``cell`` (2,): M(z) and the grid."""
    ok, out, grid = _kernels.mass_near_kernel(predicted.states, predicted.weights, Z, std_z, r2,
                                              cell[0], cell[1])
    if not ok:
        raise ValueError("mass_near: non-finite particle positions")
    return out, grid


def _grid_cell(std: np.ndarray, r2: float) -> np.ndarray:
    """Grid cells as wide as a typical gate box ((y1, y2) half-widths ``r σ``): a typical box
    then spans at most 2 × 2 cells (as :func:`.gating.gate_pairs`)."""
    # np.median(std[:, :2], axis=0) without its generic machinery (same floats: the middle
    # value, or the mean (a + b) / 2 of the two middle ones), in one kernel call (numpy's
    # sort and where on a few values cost ~8 us a frame)
    if 0 < len(std) <= _kernels.GRID_CELL_MAX:
        return _kernels.grid_cell(std, float(r2))
    s = np.sort(std[:, :2], axis=0)
    h = len(s) // 2
    med = s[h] if len(s) % 2 else (s[h - 1] + s[h]) / 2.0
    cell = 2.0 * math.sqrt(r2) * med
    return np.where(cell > 0, cell, 1.0)


def allocate_births(m_near: np.ndarray, bp: BirthParams = BirthParams()) -> np.ndarray:
    """J_z (N_z,) int64: ``J_max max(0, 1 − M(z))`` (``"complement"``) or J_max
    (``"constant"``), then, when the total exceeds ``max_births_per_frame``, every J_z scaled
    by ``max_births_per_frame / ΣJ`` and rounded down (so the total never exceeds the cap)."""
    # (numpy's floats, one kernel call: :func:`._kernels.birth_counts`)
    return _kernels.birth_counts(np.asarray(m_near, dtype=np.float64).reshape(-1),
                                 int(bp.j_max), bp.birth_allocation == "complement",
                                 int(bp.max_births_per_frame))


def log_birth_weight(Z: np.ndarray, params: PHDParams,
                     log_kappa: Optional[np.ndarray] = None,
                     log_norm: Optional[np.ndarray] = None) -> np.ndarray:
    """log of each detection's total newborn weight (N_z,): ``birth_intensity`` (paper), or,
    with ``birth_odds`` > 0 and ``log_kappa`` given, ``odds · κ(z) / ((1 − p_M) ḡ(z))`` with
    ḡ(z) the mean of g(z|x) over z's newborn (``peak · (1 + birth_spread²)^-2`` for the
    Gaussian), so that alone its newborn win ``C_b / κ = odds``.  ``log_norm``:
    ``Σ log obs_std(Z[:, 2:4])`` per detection when the caller has it."""
    bp, lk = params.birth, params.likelihood
    if bp.birth_odds <= 0 or log_kappa is None:
        return np.full(len(Z), math.log(bp.birth_intensity))
    if log_norm is None:
        log_norm = np.log(obs_std(Z[:, 2:4], lk)).sum(-1)
    log_peak = -log_norm - 0.5 * OBS_DIM * math.log(2 * math.pi)
    log_gbar = log_peak - 0.5 * OBS_DIM * math.log1p(bp.birth_spread ** 2)
    log_pd = math.log1p(-lk.p_miss) if lk.p_miss < 1 else 0.0
    return math.log(bp.birth_odds) + np.asarray(log_kappa) - log_pd - log_gbar


def _birth_weight_terms(params: PHDParams, log_kappa: Optional[np.ndarray]
                        ) -> tuple[np.ndarray, int, np.ndarray]:
    """:func:`log_birth_weight` as ``(lw_base, lw_mode, consts)`` for
    :func:`._kernels.birth_alloc_fill`, which does its arithmetic (the same operations in the
    same order): mode 1 the constant ``log birth_intensity``, mode 2 the ``birth_odds`` weight
    of ``log_kappa`` and the detections' ``Σ log σ``; ``consts`` the kernel's settings array
    (:func:`_birth_consts`, its mode's ``lw_c`` last)."""
    odds = not (params.birth.birth_odds <= 0 or log_kappa is None)
    c = _birth_consts(params, odds)
    if not odds:
        return _NO_LW, 1, c
    lkap = log_kappa
    if not (type(lkap) is np.ndarray and lkap.dtype == np.float64 and lkap.ndim == 1):
        lkap = np.asarray(lkap, dtype=np.float64).reshape(-1)
    return lkap, 2, c


#: the last settings' kernel constants per weight mode: (params, array) (one object a run)
_BIRTH_CONSTS: dict = {}


def _birth_consts(params: PHDParams, odds: bool) -> np.ndarray:
    """:func:`._kernels.birth_alloc_fill`'s ``consts`` for ``params`` (read-only; made once
    per settings object and weight mode): the birth, likelihood and size settings, then
    :func:`_weight_consts`'s ``lw_c``."""
    last = _BIRTH_CONSTS.get(odds)
    if last is not None and last[0] is params:
        return last[1]
    bp, lk = params.birth, params.likelihood
    lw_c = (_weight_consts(bp.birth_odds, lk.p_miss, bp.birth_spread, True) if odds
            else _weight_consts(bp.birth_intensity, 0.0, 0.0, False))
    c = np.array([float(int(bp.j_max)), 1.0 if bp.birth_allocation == "complement" else 0.0,
                  float(int(bp.max_births_per_frame)), lk.sigma_obs, lk.sigma_obs_min,
                  lk.sigma_obs_pos_ratio, bp.birth_spread, bp.birth_speed_mean,
                  bp.birth_speed_std, params.motion.min_size, *lw_c], dtype=np.float64)
    assert len(c) == _kernels.BIRTH_LW_C + len(lw_c)
    c.setflags(write=False)
    _BIRTH_CONSTS[odds] = (params, c)
    return c


_NO_LW = np.zeros(0, np.float64)


@lru_cache(maxsize=16)
def _weight_consts(a: float, p_miss: float, spread: float, odds: bool) -> np.ndarray:
    """The constants of :func:`_birth_weight_terms` (read-only): ``[log a]`` (a the birth
    intensity), or for ``birth_odds`` = a :func:`log_birth_weight`'s Python floats."""
    if odds:
        log_pd = math.log1p(-p_miss) if p_miss < 1 else 0.0
        c = np.array([math.log(a), log_pd, 0.5 * OBS_DIM * math.log(2 * math.pi),
                      0.5 * OBS_DIM * math.log1p(spread ** 2)])
    else:
        c = np.array([math.log(a)])
    c.setflags(write=False)
    return c


def max_births(n_z: int, bp: BirthParams) -> int:
    """The most newborn :func:`allocate_births` can give ``n_z`` detections."""
    return min(n_z * bp.j_max, bp.max_births_per_frame)


def birth(predicted: ParticleSet, Z, params: PHDParams, rng: np.random.Generator,
          log_kappa: Optional[np.ndarray] = None,
          revive: Optional[np.ndarray] = None,
          out: Optional[tuple[np.ndarray, np.ndarray]] = None,
          noise: Optional[tuple[np.ndarray, np.ndarray]] = None,
          ahead: Optional[tuple] = None) -> BirthResult:
    """Draw J_k newborn particles around the detections (maggio2007 §2; readings in the module
    docstring): ``J_z = J_max max(0, 1 − M(z))`` (capped per frame, :func:`allocate_births`),
    each detection's newborn carrying total weight ``birth_intensity`` (or the weight set by
    ``birth_odds`` from ``log_kappa``, :func:`log_birth_weight`); ``revive`` (N_z,) bool marks
    the detections that get ``revive_odds`` instead of ``birth_odds``.  Takes one word of
    ``rng``, the key of the generator the kernel draws from (:func:`._kernels.birth_fill`).
    ``out`` = (states (M, 6), log-weights (M,)) with M >= :func:`max_births`: the newborn are
    written into their first J rows.  ``noise`` = (``obs_std(Z[:, 2:4])``, its numpy ``log``)
    from a caller that has them and has checked ``Z`` (:func:`observations_noise`,
    :meth:`PHDFilter.step`); ``ahead``: the M(z) the scene model computed in its own pass
    (:meth:`SceneModel.take_birth_mass`, :func:`_mass_near`)."""
    if noise is None:
        Z, noise = observations_noise(Z, params.likelihood)
    bp, lk = params.birth, params.likelihood
    m_near, grid = _mass_near(predicted, Z, bp, lk, noise[0], ahead)
    st = key_stream(rng)
    # eq. (4), newborn branch, with γ_z ∝ p_z: every newborn of z weighs birth_intensity / J_z
    # (log_birth_weight's arithmetic, the division and the revive odds in the kernel: numpy's
    # floats, no array operation here)
    lw_base, lw_mode, consts = _birth_weight_terms(params, log_kappa)
    if lw_mode == 2 and len(lw_base) != len(Z):
        raise ValueError(f"birth: {len(lw_base)} clutter densities for {len(Z)} detections")
    if revive is not None and bp.revive_odds > bp.birth_odds > 0 and log_kappa is not None:
        revive = np.asarray(revive, dtype=np.bool_).reshape(-1)
        if len(revive) != len(Z):
            raise ValueError(f"birth: revive has {len(revive)} flags for {len(Z)} detections")
        log_revive = math.log(bp.revive_odds / bp.birth_odds)
    else:
        revive, log_revive = _NO_REVIVE, 0.0
    cap = max_births(len(Z), bp)
    if out is not None and len(out[0]) >= cap and len(out[1]) >= cap:
        states, log_w = out
    else:
        states, log_w = np.empty((cap, STATE_DIM)), np.empty(cap)
    det = np.empty(cap, np.int64)
    # one call (numba): J_z (allocate_births), then one fused pass drawing its own numbers:
    # (y, w, h) = z + spread σ(z) ε, speed (mean + std n) sqrt(w h) in a uniform direction,
    # sizes clipped to min_size
    j, n = _kernels.birth_alloc_fill(m_near, consts, lw_base, lw_mode, noise[1], revive,
                                     log_revive, Z, st, states, log_w, det)
    if n < 0:
        raise ValueError(f"birth: newborn counts {j.tolist()} do not fit the {cap} places "
                         f"(is M(z) finite? {np.asarray(m_near).tolist()})")
    # (the kernel filled float64 rows of one count: a set without the constructor's checks)
    return BirthResult(ParticleSet.unchecked(states[:n], log_w[:n]), j, m_near, det[:n], grid)


_NO_REVIVE = np.zeros(0, np.bool_)


@dataclass(frozen=True, init=False)
class UpdateResult:
    """The updated PHD (maggio2007 eq. (5)).

    particles: predicted followed by newborn, with updated weights; c_z (N_z,) C_k(z);
    kappa (N_z,) κ(z); per_det_mass (N_z,) ``C(z) / (κ(z) + C(z))``, the mass that detection z
    contributes; miss_mass ``p_M · M_{k|k-1}``.  ``particles.mass = miss_mass + sum(per_det_mass)``.
    """

    particles: ParticleSet
    c_z: np.ndarray
    kappa: np.ndarray
    per_det_mass: np.ndarray
    miss_mass: float

    def __init__(self, particles: ParticleSet, c_z: np.ndarray, kappa: np.ndarray,
                 per_det_mass: np.ndarray, miss_mass: float):
        # (a frozen dataclass's generated __init__ sets each field by object.__setattr__:
        # the instance dict directly costs a fraction; made every frame)
        d = self.__dict__
        d["particles"], d["c_z"], d["kappa"] = particles, c_z, kappa
        d["per_det_mass"], d["miss_mass"] = per_det_mass, miss_mass


class _UpdateResultLogs(UpdateResult):
    """:class:`UpdateResult` whose ``c_z`` and ``kappa`` are made (numpy's ``exp`` of ``log C``
    and ``log κ``, the same arrays) on their first read: a run reads only ``per_det_mass``
    (the 'measurement' estimates and particle-level stage data read them)."""

    def __init__(self, particles: ParticleSet, log_c: np.ndarray, log_kappa: np.ndarray,
                 per_det_mass: np.ndarray, miss_mass: float):
        d = self.__dict__
        d["particles"], d["_log_c"], d["_log_kappa"] = particles, log_c, log_kappa
        d["per_det_mass"], d["miss_mass"] = per_det_mass, miss_mass

    def __getattr__(self, name):
        d = self.__dict__
        if name == "c_z" and "_log_c" in d:
            d["c_z"] = v = np.exp(d["_log_c"])
            return v
        if name == "kappa" and "_log_kappa" in d:
            d["kappa"] = v = np.exp(d["_log_kappa"])
            return v
        raise AttributeError(name)


@dataclass(frozen=True, init=False)
class GatedGaussian:
    """``log g`` of :class:`GaussianLikelihood` on the pairs inside the update gate, left for
    :func:`update` to evaluate on the fly: one fused pass over the particles near each
    detection (a grid on their positions, :func:`._kernels.gauss_update`), with no pair
    arrays.  ``Z`` (N_z, 4) the detections, ``params`` the likelihood's settings, ``r2`` the
    squared Mahalanobis gate radius (``tail_radius2(gate_tail)``, bound in :mod:`.gating`; the
    test is in float64 here, exactly the ellipsoid).  ``noise``: ``(σ, log σ)`` of
    ``Z`` under ``params`` when the caller has them (:func:`observations_noise`; read only
    with per-detection stds).
    ``persistent`` = ``(n, grid, j)`` when the particles are ``n`` predicted ones followed by
    the newborn, ``j`` (N_z,) of each detection in turn, and ``grid`` is the one M(z)'s
    kernel bucketed the predicted on (:attr:`BirthResult.grid`): the update then buckets no
    particle again (read only with per-detection stds); a fourth item True says the ``n``
    predicted weigh the same (the update then reads none of their weights to bound them)."""

    Z: np.ndarray
    params: LikelihoodParams
    r2: float
    noise: Optional[tuple[np.ndarray, np.ndarray]] = None
    persistent: Optional[tuple[int, tuple, np.ndarray]] = None

    def __init__(self, Z: np.ndarray, params: LikelihoodParams, r2: float,
                 noise: Optional[tuple[np.ndarray, np.ndarray]] = None,
                 persistent: Optional[tuple[int, tuple, np.ndarray]] = None):
        # (a frozen dataclass's generated __init__ sets each field by object.__setattr__:
        # the instance dict directly costs a fraction; made every frame)
        d = self.__dict__
        d["Z"], d["params"], d["r2"], d["noise"], d["persistent"] = (Z, params, r2, noise,
                                                                     persistent)


#: What :func:`update` takes as the likelihood: a dense (N, N_z) matrix, one
#: :class:`~.gating.LogGPairs`, an iterable of them over disjoint sets of detections, or a
#: :class:`GatedGaussian`.
LogG = Union[np.ndarray, LogGPairs, Iterable[LogGPairs], GatedGaussian]


def update(particles: ParticleSet, log_g: LogG, log_kappa: np.ndarray,
           p_miss: float) -> UpdateResult:
    """Eq. (5) of maggio2007 (= eqs. (11)–(12) of feng2015 with their g):
    ``ω_k = [p_M + Σ_z ψ_z(x) / (κ(z) + C(z))] ω_{k|k-1}`` with ``ψ_z = (1 − p_M) g(z|x)`` and
    ``C(z) = Σ_j ψ_z(x_j) ω_j``, all in log space so far-away particles underflow gracefully.

    ``log_g`` is ``log g(z|x)`` from a :class:`Likelihood`, either

    - dense: an (N, N_z) matrix (``-inf`` where a particle cannot have produced z), or
    - sparse: a :class:`~.gating.LogGPairs` (g = 0 on every pair it does not list), or an
      iterable of them (e.g. a generator, so only one is in memory at a time), each holding
      *every* listed pair of its detections (a detection may not appear in two of them;
      :func:`gated_log_g` yields such chunks), or
    - the Gaussian g itself on the gated pairs (:class:`GatedGaussian`, what
      :meth:`PHDFilter.step` passes for a :class:`GaussianLikelihood`): evaluated inside the
      update by one numba kernel, O(N + pairs) time and O(N + N_z) memory.

    ``log_kappa`` (N_z,) is ``log κ(z)``; the filter never knows which likelihood it runs (like
    nchopin/particles' ``logG``).  The sparse form costs O(pairs + N per chunk)."""
    if not (type(log_kappa) is np.ndarray and log_kappa.dtype == np.float64
            and log_kappa.ndim == 1):
        log_kappa = np.asarray(log_kappa, dtype=np.float64).reshape(-1)
    if not 0.0 <= p_miss <= 1.0:
        raise ValueError(f"update: p_miss must be in [0, 1], got {p_miss}")
    if isinstance(log_g, np.ndarray):
        return _update_dense(particles, log_g, log_kappa, p_miss)
    if isinstance(log_g, GatedGaussian):
        return _update_gaussian(particles, log_g, log_kappa, p_miss)
    chunks = [log_g] if isinstance(log_g, LogGPairs) else log_g
    return _update_pairs(particles, chunks, log_kappa, p_miss)


def _missed_only(particles: ParticleSet, log_kappa: np.ndarray, p_miss: float) -> UpdateResult:
    """Eq. (5) with no detection or no particle: every weight × p_M, C(z) = 0."""
    n_z = len(log_kappa)
    out = ParticleSet(particles.states, particles.log_weights + _log_probs(p_miss)[0],
                      particles.labels, particles.extra)
    return UpdateResult(out, np.zeros(n_z), np.exp(log_kappa), np.zeros(n_z),
                        p_miss * particles.mass)


def _log_probs(p_miss: float) -> tuple[float, float]:
    log_pm = math.log(p_miss) if p_miss > 0 else -np.inf
    log_pd = math.log1p(-p_miss) if p_miss < 1 else -np.inf
    return log_pm, log_pd


def _update_dense(particles: ParticleSet, log_g: np.ndarray, log_kappa: np.ndarray,
                  p_miss: float) -> UpdateResult:
    """Eq. (5) on the dense (N, N_z) matrix (the reference the sparse route is tested against)."""
    lw = particles.log_weights
    log_g = np.asarray(log_g, dtype=np.float64)
    n_z = len(log_kappa)
    if log_g.shape != (len(particles), n_z):
        raise ValueError(f"update: log_g must be (N particles, N_z) = ({len(particles)}, {n_z}), "
                         f"got {log_g.shape}")
    if n_z == 0 or len(particles) == 0:
        return _missed_only(particles, log_kappa, p_miss)
    log_pm, log_pd = _log_probs(p_miss)
    m_pred = particles.mass
    kappa = np.exp(log_kappa)
    log_psi = log_pd + log_g                                            # (N, N_z)
    log_c = logsumexp(log_psi + lw[:, None], axis=0)                    # (N_z,)
    log_den = np.logaddexp(log_kappa, log_c)
    # κ = 0 and C = 0 (no clutter model, every particle dead): ψ is 0 for all, so the term is 0.
    log_den = np.where(np.isfinite(log_den), log_den, 0.0)
    terms = np.empty((len(particles), n_z + 1))
    terms[:, 0] = log_pm
    terms[:, 1:] = log_psi - log_den[None, :]
    new_lw = lw + logsumexp(terms, axis=1)
    return UpdateResult(ParticleSet(particles.states, new_lw, particles.labels, particles.extra),
                        np.exp(log_c), kappa, np.exp(log_c - log_den), p_miss * m_pred)


def _update_gaussian(particles: ParticleSet, g: GatedGaussian, log_kappa: np.ndarray,
                     p_miss: float) -> UpdateResult:
    """Eq. (5) with the Gaussian g evaluated inside the gate by :func:`._kernels.gauss_update`
    (C(z) and each particle's bracket by online log-sum-exps; the same sums as
    :func:`_update_pairs` on the gated pairs, in another order)."""
    lw = particles.log_weights
    Z = g.Z
    if not (type(Z) is np.ndarray and Z.dtype == np.float64 and Z.ndim == 2
            and Z.shape[1] == OBS_DIM):
        Z = np.asarray(Z, dtype=np.float64).reshape(-1, OBS_DIM)
    n, n_z = len(particles), len(log_kappa)
    if len(Z) != n_z:
        raise ValueError(f"update: {len(Z)} detections but {n_z} clutter densities")
    if n_z == 0 or n == 0:
        return _missed_only(particles, log_kappa, p_miss)
    log_pm, log_pd = _log_probs(p_miss)
    lk = g.params
    by_det = lk.obs_std_source == "detection"
    if by_det and g.noise is not None:
        std, log_std = g.noise
    else:
        std = obs_std(Z[:, 2:4] if by_det else particles.states[:, 4:6], lk)
        log_std = np.log(std)                   # (the kernels sum each row: numpy's sum)
    done = False
    if by_det:      # the linear route alone (weights within e^600: every PHD frame)
        equal = False
        if g.persistent is not None:            # its grid is built: no cell to size
            n_grid, grid, j_born = g.persistent[:3]
            equal, cell = len(g.persistent) > 3 and bool(g.persistent[3]), (1.0, 1.0)
        else:
            n_grid, grid, j_born, cell = n, _NO_GRID, _NO_BLOCKS, _grid_cell(std, g.r2)
        ok, done, bracket, log_c, log_mass, log_pred, lin, scale, log_share = (
            _kernels.gauss_update_linear(particles.states, lw, Z, std, log_std, log_kappa,
                                         log_pd, log_pm, float(g.r2), cell[0], cell[1],
                                         n_grid, grid, j_born, equal))
    if not done:
        cell = _grid_cell(std if by_det else np.max(std[:, :2], axis=0, keepdims=True), g.r2)
        ok, new_lw, log_c, log_mass, log_pred = _kernels.gauss_update(
            particles.states, lw, Z, std, log_std, by_det, log_kappa, log_pd, log_pm,
            float(g.r2), cell[0], cell[1])
    if not ok:
        raise ValueError("update: non-finite particle positions")
    if not done:    # (the linear route's kernel made these, the same floats)
        log_den = np.logaddexp(log_kappa, log_c)
        log_den = np.where(np.isfinite(log_den), log_den, 0.0)          # κ = C = 0: term is 0
        log_share = log_c - log_den
        out = ParticleSet(particles.states, new_lw, particles.labels, particles.extra)
        out.known_log_mass(log_mass)                                    # the kernel summed it
    else:           # the logs of the bracket made only if read (a run reads lin and the mass)
        # (the kernel summed the mass; the resampling walk reads the normalised weights)
        make = partial(_kernels.bracket_log_weights, lw, bracket)
        norm = (lin, scale) if scale > 0.0 else None
        if particles.labels is None and particles.extra is None:
            out = LazyParticleSet.unchecked(particles.states, make, log_mass, norm)
        else:
            out = LazyParticleSet(particles.states, make, particles.labels, particles.extra,
                                  log_mass=log_mass, normalised=norm)
    particles.known_log_mass(log_pred)
    # (C(z) and κ made if read: _UpdateResultLogs)
    return _UpdateResultLogs(out, log_c, log_kappa, np.exp(log_share),
                             p_miss * math.exp(log_pred))


#: "no grid yet" and "no newborn block" for :func:`._kernels.gauss_update_linear`
_NO_GRID = (0.0, 0.0, 1.0, 1.0, 0, 0, np.empty(0, np.int64), np.zeros(1, np.int64))
_NO_BLOCKS = np.empty(0, np.int64)


def _update_pairs(particles: ParticleSet, chunks: Iterable[LogGPairs], log_kappa: np.ndarray,
                  p_miss: float) -> UpdateResult:
    """Eq. (5) on sparse pairs, one chunk of detections at a time.  A chunk holds all the pairs
    of its detections, so their C(z) — hence ψ/(κ + C) — is final within the chunk; each
    particle's bracket ``p_M + Σ_z ψ/(κ + C)`` is a running log-sum-exp over the chunks."""
    lw = particles.log_weights
    n, n_z = len(particles), len(log_kappa)
    if n_z == 0 or n == 0:
        return _missed_only(particles, log_kappa, p_miss)
    log_pm, log_pd = _log_probs(p_miss)
    m_pred = particles.mass
    kappa = np.exp(log_kappa)
    # Running log-sum-exp of the bracket per particle as (shift, sum): log = shift + log(sum).
    if np.isfinite(log_pm):
        acc_shift, acc_sum = np.full(n, log_pm), np.ones(n)
    else:
        acc_shift, acc_sum = np.zeros(n), np.zeros(n)
    log_c = np.full(n_z, -np.inf)
    seen = np.zeros(n_z, dtype=bool)
    for ch in chunks:
        if not isinstance(ch, LogGPairs):
            raise TypeError(f"update: expected LogGPairs chunks, got {type(ch).__name__}")
        if len(ch) == 0:
            continue
        rows, cols = ch.rows, ch.cols
        if rows.min() < 0 or rows.max() >= n or cols.min() < 0 or cols.max() >= n_z:
            raise ValueError(f"update: pair indices out of range for {n} particles and "
                             f"{n_z} detections")
        present = np.bincount(cols, minlength=n_z) > 0
        if (present & seen).any():
            raise ValueError("update: a detection's pairs are split over two chunks (each chunk "
                             "must hold every pair of its detections)")
        seen |= present
        log_psi = ch.values + log_pd                                    # (P,)
        # C(z) = Σ ψ ω over the pairs of z: a log-sum-exp per detection.
        a = log_psi + lw[rows]
        c_max = np.full(n_z, -np.inf)
        np.maximum.at(c_max, cols, a)
        c_max = np.where(np.isfinite(c_max), c_max, 0.0)
        c_sum = np.bincount(cols, weights=np.exp(a - c_max[cols]), minlength=n_z)
        with np.errstate(divide="ignore"):
            log_c = np.where(present, np.log(c_sum) + c_max, log_c)
        log_den = np.logaddexp(log_kappa, log_c)
        log_den = np.where(np.isfinite(log_den), log_den, 0.0)          # κ = C = 0: term is 0
        t = log_psi - log_den[cols]                                     # log ψ/(κ + C)
        t_max = np.full(n, -np.inf)
        np.maximum.at(t_max, rows, t)
        shift = np.maximum(acc_shift, t_max)
        shift = np.where(np.isfinite(shift), shift, 0.0)
        acc_sum = (acc_sum * np.exp(acc_shift - shift)
                   + np.bincount(rows, weights=np.exp(t - shift[rows]), minlength=n))
        acc_shift = shift
    log_den = np.logaddexp(log_kappa, log_c)
    log_den = np.where(np.isfinite(log_den), log_den, 0.0)
    with np.errstate(divide="ignore"):
        new_lw = lw + acc_shift + np.log(acc_sum)
    return UpdateResult(ParticleSet(particles.states, new_lw, particles.labels, particles.extra),
                        np.exp(log_c), kappa, np.exp(log_c - log_den), p_miss * m_pred)


def gated_log_g(likelihood: Likelihood, states: np.ndarray, Z: np.ndarray,
                frame: Optional[Frame], params: PHDParams) -> Iterator[LogGPairs]:
    """``log g`` on the pairs inside the update gate, one chunk of detections at a time (for
    :func:`update`): the gate is the observation-noise ellipsoid (``params.likelihood``) of
    each z at Mahalanobis² ``χ²₄⁻¹(1 − gate_tail)`` (bound in :mod:`.gating`), tested in
    float32; the values come from ``likelihood.log_g_pairs`` when it has one, else from its
    dense ``log_g`` on bounded blocks (:class:`Likelihood`)."""
    lk, gp = params.likelihood, params.gating
    Z = np.asarray(Z, dtype=np.float64).reshape(-1, OBS_DIM)
    states = np.asarray(states, dtype=np.float64)
    obs = states[:, OBS_COLS]
    if lk.obs_std_source == "detection":
        std = {"std_z": obs_std(Z[:, 2:4], lk)}
    else:
        std = {"std_x": obs_std(obs[:, 2:4], lk)}
    pairs_fn = getattr(likelihood, "log_g_pairs", None)
    for ch in gate_pairs(obs, Z, tail_radius2(gp.gate_tail, OBS_DIM), budget=gp.pair_budget,
                         dtype=np.float32, **std):
        if pairs_fn is not None:
            values = pairs_fn(states, Z, ch.rows, ch.cols, frame)
        else:
            values = _dense_on_pairs(likelihood, states, Z, ch.rows, ch.cols, frame,
                                     gp.pair_budget)
        values = np.asarray(values, dtype=np.float64)
        if values.shape != ch.rows.shape:
            raise ValueError(f"{type(likelihood).__name__}.log_g_pairs: expected shape "
                             f"{ch.rows.shape} (one value per pair), got {values.shape}")
        yield LogGPairs(ch.rows, ch.cols, values)


def _dense_on_pairs(likelihood: Likelihood, states: np.ndarray, Z: np.ndarray, rows: np.ndarray,
                    cols: np.ndarray, frame: Optional[Frame], budget: int) -> np.ndarray:
    """A likelihood without ``log_g_pairs`` on pairs sorted by detection: its dense ``log_g``
    on blocks (the particles of a group of detections × those detections) of about ``budget``
    entries at most (one detection's particles × 1 when a detection alone has more)."""
    out = np.empty(len(rows))
    # Pair ranges of each detection (pairs are sorted by detection).
    edges = np.concatenate([[0], np.flatnonzero(np.diff(cols)) + 1, [len(cols)]])
    counts = np.diff(edges)
    # Greedy groups of consecutive detections with (pairs in group) x (detections) <= budget:
    # a Python loop over detections, not particles.
    a = 0
    while a < len(counts):
        b, total = a + 1, int(counts[a])
        while b < len(counts) and (total + int(counts[b])) * (b - a + 1) <= budget:
            total += int(counts[b])
            b += 1
        sl = slice(int(edges[a]), int(edges[b]))
        ur, ir = np.unique(rows[sl], return_inverse=True)
        uc, ic = np.unique(cols[sl], return_inverse=True)
        block = np.asarray(likelihood.log_g(states[ur], Z[uc], frame), dtype=np.float64)
        if block.shape != (len(ur), len(uc)):
            raise ValueError(f"{type(likelihood).__name__}.log_g: expected shape "
                             f"({len(ur)}, {len(uc)}), got {block.shape}")
        out[sl] = block[ir, ic]
        a = b
    return out


def n_resample(mass: float, rp: ResamplingParams) -> int:
    """``L_k = round(ρ M̂_{k|k})`` clipped to ``[min_particles, max_particles]`` (§2)."""
    if not mass > 0:
        return 0
    # np.clip on a scalar costs ~8 us; min/max give the same int
    return int(min(max(round(rp.rho * mass), rp.min_particles), rp.max_particles))


def resample(ps: ParticleSet, rp: ResamplingParams, rng: np.random.Generator) -> ParticleSet:
    """Draw L_k particles from ``ω̃_k / M̂_{k|k}`` and give each weight ``M̂_{k|k} / L_k`` so the
    total mass is preserved (maggio2007 §2)."""
    return _resample_set(ps, n_resample(ps.mass, rp), rng, rp.resampling)


# ----------------------------------------------------------------------------- the stateful filter

def _same(a, b) -> bool:
    """``a == b`` for settings, without the dataclass's field-tuple comparison when they are
    one object (every frame of a run)."""
    return a is b or a == b


@dataclass(frozen=True, init=False)
class PHDStepResult:
    """Every stage of one frame. ``updated.particles`` is ``predicted`` followed by
    ``birth.particles`` (so its first ``len(predicted)`` rows are the persistent particles);
    ``mass`` is M̂_{k|k} (before resampling, equal to ``resampled.mass`` up to round-off)."""

    observations: np.ndarray
    predicted: ParticleSet
    birth: BirthResult
    updated: UpdateResult
    resampled: ParticleSet
    mass: float

    def __init__(self, observations: np.ndarray, predicted: ParticleSet, birth: BirthResult,
                 updated: UpdateResult, resampled: ParticleSet, mass: float):
        # (a frozen dataclass's generated __init__ sets each field by object.__setattr__:
        # the instance dict directly costs a fraction; made every frame)
        d = self.__dict__
        d["observations"], d["predicted"], d["birth"] = observations, predicted, birth
        d["updated"], d["resampled"], d["mass"] = updated, resampled, mass

    @property
    def born(self) -> ParticleSet:
        return self.birth.particles


class PHDFilter:
    """The particle PHD filter composed from parts: the motion model (``params.motion``), the
    likelihood (any :class:`Likelihood`, default :class:`GaussianLikelihood`), the clutter
    model, the birth and the resampler — stateful only in its particles.

    ``rng`` is required (same seed, same detections → identical particles)."""

    def __init__(self, params: PHDParams | None = None, rng: np.random.Generator | None = None,
                 likelihood: Likelihood | None = None):
        if rng is None:
            raise ValueError("PHDFilter needs an explicit numpy.random.Generator")
        self.params = params if params is not None else PHDParams()
        self.likelihood: Likelihood = likelihood or GaussianLikelihood(self.params.likelihood)
        self.rng = rng
        self.particles = ParticleSet.empty(STATE_DIM)
        self.scene = SceneModel(self.params)

    @property
    def mass(self) -> float:
        return self.particles.mass

    def set_params(self, params: PHDParams) -> None:
        """New settings from the next frame on, keeping the particles and the online estimates
        (the per-second conversion of :mod:`.tracker` uses it once the frame rate is known).
        The likelihood's settings (``params.likelihood``) may change only for the Gaussian
        likelihood (a width learnt online, :mod:`.scene_noise`)."""
        if params.likelihood != self.params.likelihood:
            if type(self.likelihood) is not GaussianLikelihood:
                raise ValueError("PHDFilter.set_params: the likelihood settings cannot change "
                                 "for a likelihood other than the Gaussian")
            self.likelihood = GaussianLikelihood(params.likelihood)
            self.scene.set_likelihood(params.likelihood)
        self.params = params
        self.scene.cl, self.scene.sp = params.clutter, params.score

    def reset(self) -> None:
        self.particles = ParticleSet.empty(STATE_DIM)
        self.scene = SceneModel(self.params)

    def step(self, Z, frame: Optional[Frame] = None,
             revive: Optional[np.ndarray] = None,
             observations: Optional[np.ndarray] = None) -> PHDStepResult:
        """One frame: predict → birth → update (eq. (5) on the gated pairs:
        :class:`GatedGaussian` for the Gaussian likelihood, :func:`gated_log_g` for any other)
        → resample.  ``Z`` is (N_z, 4) ``(y1, y2, w, h)`` or a
        :class:`~pfscope.trackers.types.Detections`; ``frame`` is handed to the likelihood
        (image-based likelihoods need the pixels); ``revive`` (N_z,) bool: detections whose
        newborn get ``revive_odds`` (:func:`birth`).  ``observations``: ``Z``'s observation
        vectors when the caller has them already (``Detections.observations()``' floats, a
        C-contiguous float64 (N_z, 4) array the filter only reads; the tracker's centre
        boxes): not computed again."""
        scores = getattr(Z, "scores", None)
        p = self.params
        Z, noise = observations_noise(Z if observations is None else observations,
                                      p.likelihood)
        prev = self.particles
        # the persistent particles then the newborn in one pair of arrays: no concatenation
        n = len(prev.log_weights)       # (len(prev): a Python call, the same count)
        fused = prev.labels is None and prev.extra is None
        buf = None
        if fused:
            bp = p.birth                # (max_births, inline)
            cap = n + min(len(Z) * bp.j_max, bp.max_births_per_frame)
            buf = (np.empty((cap, STATE_DIM)), np.empty(cap))
        predicted = predict(prev, p.motion, self.rng, buf)
        # the scene model's stds are these when it has the filter's likelihood (set_params)
        log_kappa_geo, log_kappa = self.scene.log_kappa(
            Z, scores, frame, predicted,
            noise[0] if _same(self.scene.lk, p.likelihood) else None)
        born = birth(predicted, Z, p, self.rng, log_kappa_geo, revive,
                     None if buf is None else (buf[0][n:], buf[1][n:]), noise,
                     self.scene.take_birth_mass())
        m = n + len(born.particles)
        if fused and born.particles.states.base is buf[0]:
            candidates = ParticleSet.unchecked(buf[0][:m], buf[1][:m])
        else:
            candidates = predicted.concat(born.particles)
        if type(self.likelihood) is GaussianLikelihood:
            # maggio2007's Gaussian: evaluated inside the update's fused kernel
            log_g: LogG = GatedGaussian(Z, self.likelihood.params,
                                        tail_radius2(p.gating.gate_tail, OBS_DIM),
                                        noise if _same(self.likelihood.params,
                                                       p.likelihood) else None,
                                        None if born.grid is None
                                        else (n, born.grid, born.j_per_det,
                                              predicted.is_known_equal()))
        else:
            log_g = gated_log_g(self.likelihood, candidates.states, Z, frame, p)
        updated = update(candidates, log_g, log_kappa, p.likelihood.p_miss)
        self.scene.learn(scores, updated.per_det_mass)
        resampled = resample(updated.particles, p.resampling, self.rng)
        self.particles = resampled
        return PHDStepResult(Z, predicted, born, updated, resampled, updated.particles.mass)
