"""SMC-PHD filter on detections — maggio2007 §2 (recursion, eqs. (1)–(5)) with the §4 settings.

State ``x = (y1, y2, v1, v2, w, h)`` (box centre px, velocity px/frame, box size px);
observation ``z = (y1, y2, w, h)`` (``Detections.observations()``).  The PHD is carried by a
:class:`~trackers.smc.ParticleSet` whose total weight is the expected number of targets.

One frame is four pure functions, each returning new arrays (the lead's tracker logs every
stage from :class:`PHDStepResult`):

1. :func:`predict` — eqs. (1), (2), (4) for the L_{k-1} persistent particles: propagate with
   the size-aware motion model (importance function q = f, no spawning), weight × e = 0.99.
2. :func:`birth` — J_k newborn particles drawn around the detections (§2 last paragraph).
3. :func:`update` — eq. (5), vectorised over an (N particles × N_z detections) matrix.
4. :func:`resample` — L_k = ρ M̂_{k|k} particles, total mass preserved.

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
- **Resampling**: ``L_k = round(ρ M̂_{k|k})`` clipped to ``[min_particles, max_particles]``
  (a cap the paper does not have, for memory safety), each weight ``M̂_{k|k} / L_k``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Optional, Protocol

import numpy as np

from ..params import param, part, with_options
from . import motion
from ..smc.resampling import SCHEMES
from ..smc.resampling import resample as _resample_set
from ..smc.weights import ParticleSet, logsumexp
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
    """κ(z), a density in observation space (DESIGN.md): rate / volume of a gate around z."""

    clutter_rate: float = param(1.0, "clutter points per frame around a detection",
                                paper="maggio2007 §4")
    clutter_gate: float = param(0.99, "confidence of the ellipsoid V(z) in κ = rate / V "
                                      "(reading)")

    def __post_init__(self):
        _check(self, "clutter_rate", self.clutter_rate >= 0, ">= 0")
        _check(self, "clutter_gate", 0.0 < self.clutter_gate < 1.0, "in (0, 1)")


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

    def __post_init__(self):
        _check(self, "j_max", self.j_max >= 0, ">= 0")
        _check(self, "birth_intensity", self.birth_intensity > 0, "> 0")
        _check(self, "gate", 0.0 < self.gate < 1.0, "in (0, 1)")
        _check(self, "birth_allocation", self.birth_allocation in ("complement", "constant"),
               "'complement' or 'constant'")
        _check(self, "birth_spread", self.birth_spread > 0, "> 0")
        _check(self, "birth_speed_std", self.birth_speed_std >= 0, ">= 0")


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
class PHDParams:
    """The particle PHD filter, in parts; defaults are maggio2007 §4 (or §2) unless noted.
    ``with_options(PHDParams(), {"p_miss": 0.2})`` or :meth:`of` set single fields."""

    motion: MotionParams = part(MotionParams, "prediction: survival and motion model")
    likelihood: LikelihoodParams = part(LikelihoodParams, "p_M and the Gaussian g(z|x)")
    clutter: ClutterParams = part(ClutterParams, "clutter intensity κ(z)")
    birth: BirthParams = part(BirthParams, "newborn particles")
    resampling: ResamplingParams = part(ResamplingParams, "particle count after the update")

    @classmethod
    def of(cls, **options) -> "PHDParams":
        """Defaults with some fields set by leaf name: ``PHDParams.of(p_miss=0.2, rho=500)``."""
        return with_options(cls(), options)


# ----------------------------------------------------------------------------- observation model

@lru_cache(maxsize=32)
def gate_threshold(confidence: float, dof: int = OBS_DIM) -> float:
    """Squared Mahalanobis radius of the ``confidence`` ellipsoid in ``dof`` dimensions."""
    from scipy.stats import chi2  # scipy.stats is slow to import; only needed once per value

    return float(chi2.ppf(confidence, dof))


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
    if not np.all(np.isfinite(z)):
        raise ValueError("observations: non-finite values")
    if np.any(z[:, 2:4] <= 0):
        raise ValueError("observations: box width and height must be > 0")
    return z


def obs_std(sizes: np.ndarray, lk: LikelihoodParams = LikelihoodParams()) -> np.ndarray:
    """Observation-noise std ``(σ_y1, σ_y2, σ_w, σ_h)`` for boxes of ``sizes`` (..., 2) = (w, h):
    ``σ_w = max(0.15 w, 1)``, ``σ_h = max(0.15 h, 1)``, ``σ_y = σ_size / 2`` (maggio2007 §4)."""
    s = np.maximum(lk.sigma_obs * np.asarray(sizes, dtype=np.float64), lk.sigma_obs_min)
    return np.concatenate([lk.sigma_obs_pos_ratio * s, s], axis=-1)


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


class Likelihood(Protocol):
    """The single-target likelihood g(z|x) the PHD update uses (maggio2007 eq. (5), feng2015
    eqs. (11)–(12)): ``log_g`` returns the (N particles × N_z) log-likelihood matrix.  ``frame``
    gives image-based likelihoods (feng2015's DBN score) the pixels; the Gaussian ignores it."""

    def log_g(self, states: np.ndarray, Z: np.ndarray, frame: Optional[Frame]) -> np.ndarray: ...


@dataclass(frozen=True)
class GaussianLikelihood:
    """maggio2007's g(z|x): a Gaussian on (y1, y2, w, h), stds proportional to the box size."""

    params: LikelihoodParams = LikelihoodParams()

    def log_g(self, states: np.ndarray, Z: np.ndarray, frame: Optional[Frame] = None) -> np.ndarray:
        return log_likelihood(states, Z, self.params)


def log_clutter_density(Z: np.ndarray, cl: ClutterParams = ClutterParams(),
                        lk: LikelihoodParams = LikelihoodParams()) -> np.ndarray:
    """``log κ(z)`` (N_z,): ``clutter_rate`` points spread over the ``clutter_gate`` confidence
    ellipsoid of the observation noise around z (reading of maggio2007 §4, module docstring)."""
    std = obs_std(Z[:, 2:4], lk)
    r2 = gate_threshold(cl.clutter_gate, OBS_DIM)
    d = OBS_DIM
    log_unit_ball = 0.5 * d * math.log(math.pi) - math.lgamma(0.5 * d + 1)
    log_volume = log_unit_ball + 0.5 * d * math.log(r2) + np.log(std).sum(-1)
    if cl.clutter_rate > 0:
        return math.log(cl.clutter_rate) - log_volume
    return np.full(len(Z), -np.inf)


# ----------------------------------------------------------------------------- the four stages

def predict(ps: ParticleSet, mp: MotionParams, rng: np.random.Generator) -> ParticleSet:
    """Persistent particles at k: ``x ~ f(.|x_{k-1})`` (q = f, so eq. (4) reduces to the
    survival factor, no spawning β), ``ω_{k|k-1} = e · ω_{k-1}`` (eqs. (1), (2), (4))."""
    states = motion.propagate(ps.states, rng, sigma_v=mp.sigma_v, sigma_size=mp.sigma_size,
                              accel_to_position=mp.accel_to_position, min_size=mp.min_size)
    log_e = math.log(mp.p_survival) if mp.p_survival > 0 else -np.inf
    return ParticleSet(states, ps.log_weights + log_e, ps.labels, ps.extra)


@dataclass(frozen=True)
class BirthResult:
    """Newborn particles of one frame.

    particles: the J_k newborn; j_per_det (N_z,) int64 J_z; mass_near (N_z,) predicted mass
    M(z) inside the birth gate of each z; det_index (J_k,) int64 detection each newborn came from.
    """

    particles: ParticleSet
    j_per_det: np.ndarray
    mass_near: np.ndarray
    det_index: np.ndarray


def mass_near(predicted: ParticleSet, Z: np.ndarray, bp: BirthParams = BirthParams(),
              lk: LikelihoodParams = LikelihoodParams()) -> np.ndarray:
    """M(z) (N_z,): predicted mass inside the ``gate`` confidence ellipsoid of the observation
    noise around each z (maggio2007 §2, "cumulative masses M(z_{k,j}) of the propagated
    particles that are inside the 99% confidence interval")."""
    if len(predicted) == 0 or len(Z) == 0:
        return np.zeros(len(Z))
    d2 = _mahalanobis2(predicted.states, Z, obs_std(Z[:, 2:4], lk))
    inside = d2 <= gate_threshold(bp.gate, OBS_DIM)
    return predicted.weights @ inside


def birth(predicted: ParticleSet, Z, params: PHDParams, rng: np.random.Generator) -> BirthResult:
    """Draw J_k newborn particles around the detections (maggio2007 §2; readings in the module
    docstring): ``J_z = J_max max(0, 1 − M(z))``, each detection's newborn carrying total weight
    ``birth_intensity``.  Draw order: (J, 4) normals, J direction uniforms, J speed normals."""
    Z = as_observations(Z)
    bp, lk = params.birth, params.likelihood
    m_near = mass_near(predicted, Z, bp, lk)
    if bp.birth_allocation == "complement":
        j = np.rint(bp.j_max * np.maximum(0.0, 1.0 - m_near)).astype(np.int64)
    else:
        j = np.full(len(Z), int(bp.j_max), dtype=np.int64)
    det = np.repeat(np.arange(len(Z), dtype=np.int64), j)
    n = len(det)
    zr = Z[det]
    std = obs_std(zr[:, 2:4], lk)
    eps = rng.standard_normal((n, OBS_DIM))
    theta = rng.uniform(0.0, 2.0 * math.pi, n)
    speed_n = rng.standard_normal(n)
    obs = zr + bp.birth_spread * std * eps
    scale = np.sqrt(zr[:, 2] * zr[:, 3])
    speed = (bp.birth_speed_mean + bp.birth_speed_std * speed_n) * scale
    states = np.empty((n, STATE_DIM))
    states[:, OBS_COLS] = obs
    states[:, 2] = speed * np.cos(theta)
    states[:, 3] = speed * np.sin(theta)
    states[:, 4:6] = np.maximum(states[:, 4:6], params.motion.min_size)
    # eq. (4), newborn branch, with γ_z ∝ p_z: every newborn of z weighs birth_intensity / J_z.
    log_w = math.log(bp.birth_intensity) - np.log(np.maximum(j, 1))[det]
    return BirthResult(ParticleSet(states, log_w), j, m_near, det)


@dataclass(frozen=True)
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


def update(particles: ParticleSet, log_g: np.ndarray, log_kappa: np.ndarray,
           p_miss: float) -> UpdateResult:
    """Eq. (5) of maggio2007 (= eqs. (11)–(12) of feng2015 with their g):
    ``ω_k = [p_M + Σ_z ψ_z(x) / (κ(z) + C(z))] ω_{k|k-1}`` with ``ψ_z = (1 − p_M) g(z|x)`` and
    ``C(z) = Σ_j ψ_z(x_j) ω_j``, all in log space so far-away particles underflow gracefully.

    ``log_g`` (N, N_z) is ``log g(z|x)`` from a :class:`Likelihood` (``-inf`` where a particle
    cannot have produced z); ``log_kappa`` (N_z,) is ``log κ(z)``; the filter never knows which
    likelihood it runs (like nchopin/particles' ``logG``)."""
    lw = particles.log_weights
    log_g = np.asarray(log_g, dtype=np.float64)
    log_kappa = np.asarray(log_kappa, dtype=np.float64).reshape(-1)
    n_z = len(log_kappa)
    if log_g.shape != (len(particles), n_z):
        raise ValueError(f"update: log_g must be (N particles, N_z) = ({len(particles)}, {n_z}), "
                         f"got {log_g.shape}")
    if not 0.0 <= p_miss <= 1.0:
        raise ValueError(f"update: p_miss must be in [0, 1], got {p_miss}")
    log_pm = math.log(p_miss) if p_miss > 0 else -np.inf
    log_pd = math.log1p(-p_miss) if p_miss < 1 else -np.inf
    m_pred = particles.mass
    kappa = np.exp(log_kappa)
    if n_z == 0 or len(particles) == 0:
        out = ParticleSet(particles.states, lw + log_pm, particles.labels, particles.extra)
        return UpdateResult(out, np.zeros(n_z), kappa, np.zeros(n_z), p_miss * m_pred)
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


def n_resample(mass: float, rp: ResamplingParams) -> int:
    """``L_k = round(ρ M̂_{k|k})`` clipped to ``[min_particles, max_particles]`` (§2)."""
    if not mass > 0:
        return 0
    return int(np.clip(round(rp.rho * mass), rp.min_particles, rp.max_particles))


def resample(ps: ParticleSet, rp: ResamplingParams, rng: np.random.Generator) -> ParticleSet:
    """Draw L_k particles from ``ω̃_k / M̂_{k|k}`` and give each weight ``M̂_{k|k} / L_k`` so the
    total mass is preserved (maggio2007 §2)."""
    return _resample_set(ps, n_resample(ps.mass, rp), rng, rp.resampling)


# ----------------------------------------------------------------------------- the stateful filter

@dataclass(frozen=True)
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

    @property
    def mass(self) -> float:
        return self.particles.mass

    def reset(self) -> None:
        self.particles = ParticleSet.empty(STATE_DIM)

    def step(self, Z, frame: Optional[Frame] = None) -> PHDStepResult:
        """One frame: predict → birth → update (eq. (5)) → resample.  ``Z`` is (N_z, 4)
        ``(y1, y2, w, h)`` or a :class:`~pfscope.trackers.types.Detections`; ``frame`` is handed
        to the likelihood (image-based likelihoods need the pixels)."""
        Z = as_observations(Z)
        p = self.params
        predicted = predict(self.particles, p.motion, self.rng)
        born = birth(predicted, Z, p, self.rng)
        candidates = predicted.concat(born.particles)
        log_g = self.likelihood.log_g(candidates.states, Z, frame)
        log_kappa = log_clutter_density(Z, p.clutter, p.likelihood)
        updated = update(candidates, log_g, log_kappa, p.likelihood.p_miss)
        resampled = resample(updated.particles, p.resampling, self.rng)
        self.particles = resampled
        return PHDStepResult(Z, predicted, born, updated, resampled, updated.particles.mass)
