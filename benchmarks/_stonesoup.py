"""Stone Soup's SMC-PHD filter as a pipeline lane, for the speed and accuracy comparison of
``benchmarks/bench.py`` (issue 12; issue 11 needs the accuracy side).

Optional: needs the ``bench`` extra (``pip install -e .[bench]``, i.e. ``stonesoup``).
:func:`available` says whether it is installed (and why not).

What runs is Stone Soup's own code: ``SMCPHDPredictor`` (expansion birth scheme),
``SMCPHDUpdater`` (with ``SystematicResampler``) on ``MultipleHypothesis`` of one missed-detection
hypothesis plus one hypothesis per detection, as in Stone Soup's SMC-PHD tutorial. The model is
pfscope's PHD filter's, written with Stone Soup components:

- state ``(x, vx, y, vy, w, h)``; ``CombinedLinearGaussianTransitionModel`` of a
  ``ConstantVelocity`` per axis (noise from pfscope's ``sigma_v`` at the scene's mean size) and a
  ``RandomWalk`` per size (pfscope's ``sigma_size``); survival 0.99 per frame;
- one ``LinearGaussian`` measurement model per detection, its noise sized by the detection as in
  pfscope (``obs_std_source='detection'``: σ_w = max(sigma_obs · w, sigma_obs_min),
  σ_x = sigma_obs_pos_ratio · σ_w, ...; paper: 0.15, 1 px, 0.5);
- births sampled around the frame's detections as pfscope's (same spreads), birth rate 0.01 per
  detection, p_D = 1 − p_M = 0.95;
- clutter intensity (``clutter="pfscope"``, the default): pfscope's κ(z) of the preset
  (``phd.filter.log_clutter_density``: the clutter rate spread over the gate volume V(z) of the
  observation noise around z), its geometric mean over the frame's detections, set on the
  updater before each frame (Stone Soup's updater takes one intensity for all detections);
  ``clutter="uniform"``: the scene's true clutter rate spread uniformly over the image and the
  size range (much lower: every new detection then claims nearly one target);
  ``clutter="oracle"``: the *true model of the scene* (``truth``, from
  ``_common.scene_truth``): the true clutter density (rate / (image area × area of the
  clutter's (w, h) support), the scene's clutter being uniform over both), the true p_D, and
  the true measurement noise (the scene's box noise, full covariance of (cx, cy, w, h) at the
  detection's size) instead of pfscope's; motion, survival and births stay pfscope's
  (birth mass 0.01 per detection, which against the true, tiny κ makes every clutter
  detection a target of mass ≈ 1);
- ``birth="truth"`` (with ``clutter="oracle"``): births in the true model's units as well.
  The scene's targets are all there at frame 1 and none appear later, so the birth intensity
  is uniform over the observation space with B_1 = the number of targets on frame 1 and a
  floor ``birth_floor`` per frame after (with none at all a target missed on frame 1 could
  never start). Stone Soup still samples the newborn particles around the detections (same
  particles as pfscope); their total mass is set so that each detection's newborn term equals
  the uniform birth's: p_D ∫ g(z|x) m_b K_z(x) dx = p_D B_k / V, i.e. m_b = B_k / (V ∫ g K_z)
  (V = image area × clutter size area, ∫ g K_z = N(0; 0, R(z) + Σ_K(z)) on (cx, cy, w, h),
  geometric mean over the frame's detections).

  The birth intensity after frame 1 is the scene's true birth rate (``truth["birth_rate"]``:
  new ids per frame after the first, 0 on ``targets_scene``), at least ``birth_floor``.
- ``extract="measurement"``: the estimates are read per detection, as in Ristic, Clark and Vo
  (2010, "Improved SMC implementation of the PHD filter") and Stone Soup's ``SMCPHDInitiator``:
  detection z's share of the updated PHD, ``W_z = Σ_i w_i^z`` (the updater's weights per
  hypothesis), and where ``W_z > 0.5`` one estimate at the mean of the particles weighted by
  ``w_i^z``.  ``extract="kmeans"`` (the default) leaves the estimates to the benchmark
  (k-means of round(mass) centres of the resampled particles).

``fps``: the per-frame settings are those of the pfscope lane's preset at this frame rate
(``params.at_fps``: the ``practical`` preset's are per second); None: the preset's fields as
given (``paper``).

**Same particle budget.** The lane runs right after a pfscope PHD lane in the same pipeline run
and copies, every frame, that lane's particle counts: the number of newborn particles J_k (as
``birth_probability = J_k / L_{k-1}``) and the number kept after resampling L_k (as the updater's
``num_samples``), so both filters update exactly as many particles on every frame. Timed: the
predictor, building the hypotheses and the updater (with its resampling); the lane's
``step_seconds`` is that.

``noise``: Stone Soup's ``SMCPHDUpdater`` evaluates ``measurement_model.logpdf(detection,
prediction, noise=True)``, which draws a fresh measurement-noise sample per particle and
detection inside the likelihood. ``noise=False`` overrides ``_get_measurement_loglikelihoods`` to
pass ``noise=False`` (the textbook likelihood; everything else unchanged).
"""

from __future__ import annotations

import datetime
import math

import numpy as np

STATE_DIM = 6


def available() -> str | None:
    """None when Stone Soup can be imported, else a one-line reason."""
    try:
        import stonesoup  # noqa: F401
    except ImportError as e:
        return (f"Stone Soup comparison skipped: stonesoup is not installed ({e.name}); "
                f"pip install -e '.[bench]'")
    return None


def version() -> str:
    import stonesoup

    return getattr(stonesoup, "__version__", "?")


class _DetectionBirthSampler:
    """Birth particles around the current frame's detections (pfscope's birth spreads).

    Stone Soup's predictor calls ``sample(params={'num_samples': n}, timestamp=...,
    random_state=...)``; the lane sets :attr:`Z` (N_z, 4) ``(cx, cy, w, h)`` before predicting."""

    def __init__(self, rng: np.random.Generator, spread: float = 1.0, speed_std: float = 0.1,
                 lk=None):
        self.rng, self.spread, self.speed_std, self.lk = rng, spread, speed_std, lk
        self.pos_ratio = 0.5 if lk is None else lk.sigma_obs_pos_ratio
        self.Z = np.zeros((0, 4))

    def sample(self, params, timestamp=None, random_state=None, **kwargs):
        from stonesoup.types.array import StateVectors
        from stonesoup.types.state import ParticleState

        n = int(params["num_samples"])
        Z = self.Z
        sv = np.zeros((STATE_DIM, n))
        if n and len(Z):
            pick = Z[self.rng.integers(0, len(Z), n)]
            sw, sh = _obs_std(pick[:, 2], self.lk), _obs_std(pick[:, 3], self.lk)
            e = self.rng.standard_normal((4, n)) * self.spread
            s = np.sqrt(pick[:, 2] * pick[:, 3]) * self.speed_std
            v = self.rng.standard_normal((2, n)) * s
            sv[0] = pick[:, 0] + e[0] * self.pos_ratio * sw
            sv[2] = pick[:, 1] + e[1] * self.pos_ratio * sh
            sv[1], sv[3] = v
            sv[4] = np.maximum(pick[:, 2] + e[2] * sw, 1.0)
            sv[5] = np.maximum(pick[:, 3] + e[3] * sh, 1.0)
        return ParticleState(StateVectors(sv), log_weight=np.full(n, -math.log(max(n, 1))),
                             timestamp=timestamp)


def _obs_std(size, lk=None):
    """pfscope's observation std of a size (``sigma_obs`` × size, at least ``sigma_obs_min``)."""
    ratio, floor = (0.15, 1.0) if lk is None else (lk.sigma_obs, lk.sigma_obs_min)
    return np.maximum(ratio * np.asarray(size, dtype=float), floor)


class StoneSoupPHDLane:
    """A pipeline lane (Tracker protocol) running Stone Soup's SMC-PHD on the detections, with
    the particle counts of the pfscope lane ``budget_from`` (a :class:`PHDTracker`) that steps
    before it in the same run (``births()`` returns that lane's J_k of the current frame).
    Reports no tracks; :attr:`mass` (PHD mass after the update) and :attr:`states` (the
    particles, ``(N, 6)`` in pfscope's order ``(cx, cy, vx, vy, w, h)``) are read by the
    benchmark's hooks."""

    name = "stonesoup-smcphd"
    paper = "Vo, Singh, Doucet 2003 (Stone Soup SMCPHDUpdater)"
    stages = ("filter",)
    needs_detections = True
    needs_image = False

    def __init__(self, budget_from, births, *, width: float, height: float,
                 size_range=(10.0, 200.0), noise: bool = True, seed: int = 0,
                 mean_size: float = 40.0, clutter_rate: float = 5.0,
                 clutter: str = "pfscope", fps: float | None = None,
                 truth: dict | None = None, birth: str = "pfscope",
                 birth_floor: float = 0.04, extract: str = "kmeans",
                 extract_threshold: float = 0.5):
        from stonesoup.models.transition.linear import (
            CombinedLinearGaussianTransitionModel,
            ConstantVelocity,
            RandomWalk,
        )
        from stonesoup.predictor.particle import SMCPHDPredictor
        from stonesoup.resampler.particle import SystematicResampler
        from stonesoup.types.array import StateVectors
        from stonesoup.types.state import ParticleState
        from stonesoup.updater.particle import SMCPHDUpdater

        # Stone Soup draws its transition and measurement noise from numpy's global generator
        # (its models have no seed here): seed it, so the same seed gives the same run
        if clutter not in ("pfscope", "uniform", "oracle"):
            raise ValueError(f"clutter must be 'pfscope', 'uniform' or 'oracle', got {clutter!r}")
        if clutter == "oracle" and truth is None:
            raise ValueError("clutter='oracle' needs truth (the scene's p_detect, "
                             "clutter_density, box_noise)")
        if birth not in ("pfscope", "truth"):
            raise ValueError(f"birth must be 'pfscope' or 'truth', got {birth!r}")
        if birth == "truth" and clutter != "oracle":
            raise ValueError("birth='truth' needs clutter='oracle'")
        if extract not in ("kmeans", "measurement"):
            raise ValueError(f"extract must be 'kmeans' or 'measurement', got {extract!r}")
        self.birth = birth
        self.extract = extract
        self.extract_threshold = float(extract_threshold)
        #: (N, 2) per-measurement estimates of the frame (``extract="measurement"``), else None
        self.estimates = None
        self.birth_floor = float(birth_floor)
        np.random.seed(seed)
        self.budget_from = budget_from
        self.births = births            # () -> J_k of the pfscope lane at this frame
        self.noise = noise
        self.truth = truth if clutter == "oracle" else None
        self.rng = np.random.default_rng(seed)
        params = budget_from.params if fps is None else budget_from.params.at_fps(fps)
        fp = self.filter_params = params.filter
        q_pos = (fp.motion.sigma_v * mean_size) ** 2
        q_size = (fp.motion.sigma_size * mean_size) ** 2
        self.transition = CombinedLinearGaussianTransitionModel(
            [ConstantVelocity(q_pos), ConstantVelocity(q_pos), RandomWalk(q_size),
             RandomWalk(q_size)])
        self.lk = fp.likelihood
        self.sampler = _DetectionBirthSampler(self.rng, fp.birth.birth_spread,
                                              fp.birth.birth_speed_std, fp.likelihood)
        self.predictor = SMCPHDPredictor(
            transition_model=self.transition,
            death_probability=-math.log(fp.motion.p_survival),  # survival = exp(-λ Δt), Δt 1 s
            birth_probability=0.1, birth_rate=0.01, birth_sampler=self.sampler)
        lo, hi = size_range
        volume = float(width) * float(height) * (hi - lo) ** 2
        cls = _updater_class(noise)
        p_detect = 1.0 - fp.likelihood.p_miss
        intensity = clutter_rate / volume
        if self.truth is not None:
            p_detect = float(self.truth["p_detect"])
            intensity = float(self.truth["clutter_density"])
        self.updater = cls(measurement_model=None, resampler=SystematicResampler(),
                           prob_detect=p_detect, clutter_intensity=intensity)
        self.clutter = clutter
        self.uniform_intensity = intensity
        self.t0 = datetime.datetime(2000, 1, 1)
        # an empty filter cannot grow in Stone Soup (births are a fraction of the particles):
        # start from one particle of negligible weight
        self.state = ParticleState(StateVectors(np.zeros((STATE_DIM, 1))),
                                   log_weight=np.array([-700.0]), timestamp=self.t0)
        self.mass = 0.0
        self.states = np.zeros((0, STATE_DIM))
        self.n_update = 0               # particles in this frame's update (prediction size)

    def config(self) -> dict:
        return {"tracker": self.name, "noise": self.noise, "clutter": self.clutter,
                "prob_detect": float(self.updater.prob_detect),
                "truth": self.truth, "birth": self.birth, "birth_floor": self.birth_floor,
                "extract": self.extract, "extract_threshold": self.extract_threshold}

    def _birth_rate(self, frame_index: int, Z: np.ndarray) -> float:
        """Total newborn mass of the frame: pfscope's 0.01 per detection, or (``birth='truth'``)
        the uniform true birth B_k over V carried by kernels around the detections."""
        if self.birth == "pfscope" or not len(Z):
            return 0.01 * len(Z)
        B = (float(self.truth["targets"]) if frame_index <= 1 else
             max(float(self.truth.get("birth_rate", 0.0)), self.birth_floor))
        V = float(self.truth["clutter_rate"]) / float(self.truth["clutter_density"])
        lk, sp = self.lk, self.sampler.spread
        log_int = []
        for z in Z:
            sw, sh = _obs_std(z[2], lk), _obs_std(z[3], lk)
            r = lk.sigma_obs_pos_ratio
            S = self._measurement_covar(z) + np.diag(
                [(sp * r * sw) ** 2, (sp * r * sh) ** 2, (sp * sw) ** 2, (sp * sh) ** 2])
            log_int.append(-2.0 * math.log(2 * math.pi) - 0.5 * np.linalg.slogdet(S)[1])
        m_b = B / (V * math.exp(float(np.mean(log_int))))
        return max(m_b * len(Z), 1e-300)

    def _measurement_covar(self, z: np.ndarray) -> np.ndarray:
        """Noise covariance of a detection ``z = (cx, cy, w, h)``: pfscope's (diagonal, sized
        by the detection) or, for the oracle, the scene's true one: box noise ``s`` × (w, h, w,
        h) on (x, y, w, h), so cx = x + w/2 has variance 1.25 (s w)² and covariance (s w)²/2
        with w."""
        if self.truth is not None:
            s = float(self.truth["box_noise"])
            a, b = (s * z[2]) ** 2, (s * z[3]) ** 2
            return np.array([[1.25 * a, 0.0, 0.5 * a, 0.0], [0.0, 1.25 * b, 0.0, 0.5 * b],
                             [0.5 * a, 0.0, a, 0.0], [0.0, 0.5 * b, 0.0, b]])
        sw, sh = _obs_std(z[2], self.lk), _obs_std(z[3], self.lk)
        r = self.lk.sigma_obs_pos_ratio
        return np.diag([(r * sw) ** 2, (r * sh) ** 2, sw ** 2, sh ** 2])

    def finish(self):
        return []

    def step(self, frame, detections, level=None):
        from pfscope.trackers.api import StepResult
        from pfscope.trackers.types import TrackSet
        from stonesoup.models.measurement.linear import LinearGaussian
        from stonesoup.types.detection import Detection, MissedDetection
        from stonesoup.types.hypothesis import SingleHypothesis
        from stonesoup.types.multihypothesis import MultipleHypothesis

        f = self.budget_from.filter
        L_prev = len(self.state)
        J = int(self.births())
        L_next = max(len(f.particles), 1)
        ts = self.t0 + datetime.timedelta(seconds=frame.index)
        b = detections.boxes if detections is not None else np.zeros((0, 4))
        Z = np.c_[b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2, b[:, 2], b[:, 3]]
        self.sampler.Z = Z
        J = max(J, 1) if len(Z) else 0
        self.predictor.birth_probability = J / L_prev
        self.predictor.birth_rate = max(self._birth_rate(frame.index, Z), 1e-300)
        if J == 0:  # no detection: Stone Soup's expansion scheme needs >= 1 newborn
            self.predictor.birth_probability = 1.0 / L_prev
            self.sampler.Z = np.array([[0.0, 0.0, 1.0, 1.0]])
        self.updater.num_samples = L_next
        if self.clutter == "pfscope" and len(Z):
            from pfscope.trackers.phd.filter import log_clutter_density

            fp = self.filter_params
            self.updater.clutter_intensity = float(
                np.exp(np.mean(log_clutter_density(Z, fp.clutter, fp.likelihood))))
        prediction = self.predictor.predict(self.state, timestamp=ts)
        self.n_update = len(prediction)
        hyps = [SingleHypothesis(prediction, MissedDetection(timestamp=ts))]
        for z in Z:
            model = LinearGaussian(ndim_state=STATE_DIM, mapping=(0, 2, 4, 5),
                                   noise_covar=self._measurement_covar(z))
            hyps.append(SingleHypothesis(prediction, Detection(z.reshape(4, 1), timestamp=ts,
                                                               measurement_model=model)))
        self.state = self.updater.update(MultipleHypothesis(hyps))
        if self.extract == "measurement":
            self.estimates = _per_measurement(prediction, self.updater.last_log_weights,
                                              self.extract_threshold)
        lw = np.asarray(self.state.log_weight, dtype=float)
        self.mass = float(np.exp(np.logaddexp.reduce(lw))) if len(lw) else 0.0
        sv = np.asarray(self.state.state_vector, dtype=float)
        self.states = sv[[0, 2, 1, 3, 4, 5]].T
        return StepResult(TrackSet(np.zeros(0, np.int64), np.zeros((0, 4))))


def _per_measurement(prediction, log_w: np.ndarray, threshold: float) -> np.ndarray:
    """Per-measurement estimates (Ristic, Clark, Vo 2010): ``log_w`` (particles, 1 + N_z) are
    the update's log weights per hypothesis (column 0 the missed detection); detection j gives
    an estimate where its share ``W_j = Σ_i w_ij`` exceeds ``threshold``, at the particles'
    (x, y) mean weighted by ``w_ij``.  Returns (n, 2)."""
    from scipy.special import logsumexp

    if log_w is None or log_w.shape[1] < 2:
        return np.zeros((0, 2))
    lw = log_w[:, 1:]
    tot = logsumexp(lw, axis=0)
    keep = np.flatnonzero(np.exp(tot) > threshold)
    if not len(keep):
        return np.zeros((0, 2))
    sv = np.asarray(prediction.state_vector, dtype=float)
    w = np.exp(lw[:, keep] - tot[keep])                 # (particles, kept), columns sum to 1
    return np.c_[sv[0] @ w, sv[2] @ w]


def _updater_class(noise: bool):
    """``SMCPHDUpdater`` (``noise=False``: without the noise draw in its likelihood) that keeps
    the last update's log weights per hypothesis (``last_log_weights``) for the per-measurement
    extraction; the update itself is Stone Soup's, unchanged."""
    from stonesoup.updater.particle import SMCPHDUpdater

    base = SMCPHDUpdater if noise else _no_noise_class()

    class KeepingSMCPHDUpdater(base):
        last_log_weights = None

        def get_log_weights_per_hypothesis(self, hypotheses):
            self.last_log_weights = super().get_log_weights_per_hypothesis(hypotheses)
            return self.last_log_weights

    return KeepingSMCPHDUpdater


def _no_noise_class():
    from stonesoup.updater.particle import SMCPHDUpdater

    class NoNoiseSMCPHDUpdater(SMCPHDUpdater):
        """``SMCPHDUpdater`` whose likelihood does not draw measurement noise."""

        def _get_measurement_loglikelihoods(self, prediction, detections):
            g = np.zeros((prediction.state_vector.shape[1], len(detections)))
            for i, detection in enumerate(detections):
                model = self._check_measurement_model(detection.measurement_model)
                g[:, i] = model.logpdf(detection, prediction, noise=False)
            return g

    return NoNoiseSMCPHDUpdater

