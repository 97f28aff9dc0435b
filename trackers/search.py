"""The parameter search behind ``pfscope tune`` (the engine side: study, trials, scoring; no
recording here -- the app's :mod:`pfscope.viewer_app.tune` keeps the command line and the
Rerun recording of the study).  Search a tracker's documented parameters with Optuna against
a sequence's ground truth.

    pfscope tune SEQUENCE [--tracker phd] [--trials N] [--metric hota|idf1|mota]
                 [--frames A:B] [--holdout A:B] [--jobs J] [--seed S] [--out best.toml]

How it works:

- **Search space.**  A tracker class may declare ``tune_space`` (names, or ``"name=lo:hi"``);
  else :data:`DEFAULT_SPACES` names the parameters searched for the built-in trackers; else
  every positive float parameter is searched.  ``--space NAME[=LO:HI[:log|:lin]]`` replaces
  the list.  A name without a range gets one derived from its value in the starting preset:
  log-uniform over [v/3, 3v] (integers: rounded, at least 1), or, for a probability
  0.9 <= v < 1, log-uniform over its complement 1 - v in [(1-v)/3, 3(1-v)];
  bounds the parameter dataclass refuses are pulled back towards v.  A leaf name (``sigma_v``)
  sets every field of that name, as ``--set`` does.
- **Trials.**  Each trial runs the engine's pipeline (:func:`pfscope.trackers.pipeline.run`)
  with no recording (``level=None``) over the tuned-on frames and scores the tracks against
  the ground truth; the objective is the chosen metric (mean over ``--trial-seeds`` tracker
  seeds).  A tracker that needs no image gets a blank image of the right size (frames are
  not decoded): the tracks are the same.  The starting preset's values are trial 0.
- **Determinism.**  Optuna's TPE sampler is seeded; trials are asked in rounds of
  ``--batch`` (default 4), run (in parallel over ``--jobs`` processes) and told in trial order,
  so the result depends on the seed and ``--batch``, not on ``--jobs`` or on timing.
- **Honest scores.**  The best and the starting parameters are then run over tuned-on and
  held-out frames (``--holdout``, default the rest of the sequence) for ``--eval-seeds``
  seeds; the table names which frames were tuned on.
- **Outputs.**  ``--out`` (TOML, written atomically): every parameter, the tuned ones marked,
  and a ``[tune]`` table saying how they were found; ``pfscope record --params FILE`` reads
  it.  ``--study-out``: a Rerun recording of the study (objective, best-so-far and each
  parameter per trial on a ``trial`` timeline, the log, the final table).  ``--best-out``: the
  best parameters' recording (``pfscope record``'s, over tuned-on and held-out frames).

Optuna is an optional extra: ``pip install "pfscope[tune]"``.
"""

from __future__ import annotations

import math
import os
import re
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from .errors import InputError
from .jobs import stop_requested

#: ``--metric`` → the score key maximised.
METRICS = {"hota": "HOTA", "idf1": "IDF1", "mota": "MOTA"}
#: Columns of the final table.
TABLE_KEYS = ("MOTA", "IDF1", "HOTA", "FP", "FN", "IDSW")
#: Parameters searched by default, per built-in tracker (names as ``--set`` takes them; a
#: leaf name sets every field of that name).  The others: their class's ``tune_space``, or
#: every positive float parameter.
DEFAULT_SPACES: dict[str, tuple[str, ...]] = {
    # min_length's range stays within depth's lower bound + 1 (AssocParams: the report lag
    # min_length - 1 must not exceed depth), so no trial is spent on a refused combination
    "phd": ("p_miss", "sigma_v", "sigma_obs", "clutter_rate", "birth_intensity", "clusters.T",
            "assoc.depth=10:250:log", "assoc.min_length=1:11:log", "assoc.gate",
            "assoc.speed_prior"),
    "mt": ("depth=10:250:log", "min_length=1:11:log", "gate", "sigma_v", "sigma_obs",
           "speed_prior"),
}
#: The same for a preset whose settings are per second (``rate.per_second``, the practical
#: presets): there the per-frame fields (sigma_v, depth, min_length, speed_prior, p_survival,
#: birth odds) are derived from the ``rate.*`` fields each frame, so those are searched.
DEFAULT_SPACES_PER_SECOND: dict[str, tuple[str, ...]] = {
    "phd": ("p_miss", "filter.likelihood.sigma_obs", "clutter_rate", "clusters.T", "assoc.gate",
            "rate.accel_per_s", "rate.birth_odds_per_s", "rate.gap_s", "rate.min_track_s",
            "rate.survival_per_s"),
    "mt": ("gate", "sigma_obs", "rate.accel_per_s", "rate.birth_speed_per_s", "rate.gap_s",
           "rate.min_track_s"),
}
#: Log-range factor around a parameter's starting value (a probability near 1: of 1 - v).
#: 5 was tried first: 40 trials on PETS09-S2L1 1-400 found nothing better than the paper
#: preset, most of them far off (HOTA 0 for a quarter); 3 keeps the search near the preset.
FACTOR = 3.0
INSTALL_HINT = 'pfscope tune needs Optuna: pip install "pfscope[tune]" (or pip install optuna)'


def import_optuna():
    """Optuna, quiet; a one-line :class:`InputError` saying how to install it when absent."""
    try:
        import optuna
    except ImportError:
        raise InputError(INSTALL_HINT) from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    return optuna


# ------------------------------------------------------------------ search space

@dataclass(frozen=True)
class Dim:
    """One searched parameter.  ``name``: the option name (dotted or leaf); ``kind``: ``float``
    or ``int``; ``complement``: the search runs over ``1 - value`` (probabilities near 1)."""

    name: str
    kind: str
    low: float
    high: float
    log: bool = True
    complement: bool = False

    @property
    def label(self) -> str:
        return f"1-{self.name}" if self.complement else self.name

    def distribution(self):
        from optuna.distributions import FloatDistribution, IntDistribution

        if self.kind == "int":
            return IntDistribution(int(self.low), int(self.high), log=self.log)
        return FloatDistribution(float(self.low), float(self.high), log=self.log)

    def value(self, x: float) -> Any:
        """The parameter's value for the sampled ``x``."""
        if self.kind == "int":
            return int(x)
        return float(1.0 - x) if self.complement else float(x)

    def sample_of(self, v: Any) -> Optional[float]:
        """The sampled ``x`` giving value ``v`` (None when outside the range)."""
        x = (1.0 - float(v)) if self.complement else v
        if self.kind == "int":
            x = int(x)
        return x if self.low <= x <= self.high else None

    def describe(self) -> str:
        scale = "log" if self.log else "lin"
        rng = f"{self.low:.4g}..{self.high:.4g} ({scale})"
        return f"{self.name}: 1 - [{rng}]" if self.complement else f"{self.name}: {rng}"


def parse_space_spec(text: str) -> tuple[str, Optional[tuple[float, float, Optional[bool]]]]:
    """``"p_miss"`` → (name, None); ``"p_miss=0.01:0.5"`` / ``"depth=5:100:lin"`` → (name,
    (lo, hi, log or None))."""
    name, eq, rest = str(text).partition("=")
    name = name.strip()
    if not name:
        raise InputError(f"--space {text!r}: expected NAME or NAME=LO:HI[:log|:lin]")
    if not eq:
        return name, None
    parts = [p.strip() for p in rest.split(":")]
    try:
        lo, hi = float(parts[0]), float(parts[1])
        scale = parts[2].lower() if len(parts) > 2 else None
        if len(parts) > 3 or scale not in (None, "log", "lin"):
            raise ValueError
    except (ValueError, IndexError):
        raise InputError(f"--space {text!r}: expected NAME=LO:HI[:log|:lin], e.g. "
                         f"p_miss=0.01:0.5:log") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise InputError(f"--space {text!r}: need finite LO < HI")
    if scale == "log" and lo <= 0:
        raise InputError(f"--space {text!r}: a log range needs LO > 0")
    return name, (lo, hi, None if scale is None else scale == "log")


def _targets(params: Any, name: str) -> list[tuple[str, Any]]:
    from pfscope.trackers.params import leaves

    vals = [(n, v) for n, _, v in leaves(params)]
    exact = [(n, v) for n, v in vals if n == name]
    return exact or [(n, v) for n, v in vals if n.rsplit(".", 1)[-1] == name]


def _valid(params: Any, name: str, value: Any) -> bool:
    from pfscope.trackers.params import with_options

    try:
        with_options(params, {name: value})
        return True
    except (ValueError, TypeError):
        return False


def derive_dim(params: Any, name: str, rng=None) -> Dim:
    """The :class:`Dim` of option ``name`` for ``params`` (module docstring); ``rng`` =
    (lo, hi, log or None) gives the range explicitly."""
    targets = _targets(params, name)
    if not targets:
        raise InputError(f"--space {name}: no such parameter (`pfscope trackers` lists them)")
    v = targets[0][1]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"--space {name}: only numeric parameters can be searched "
                         f"({targets[0][0]} is {v!r})")
    kind = "int" if isinstance(v, int) else "float"
    if rng is not None:
        lo, hi, log = rng
        if log is None:
            log = lo > 0 and hi / lo >= 10
        if kind == "int":
            lo, hi = math.ceil(lo), math.floor(hi)
            if lo >= hi:
                raise InputError(f"--space {name}: integer range {lo}..{hi} is empty")
        return Dim(name, kind, lo, hi, bool(log))
    if not math.isfinite(v) or v <= 0:
        raise InputError(f"--space {name}: its value {v!r} gives no range: give one "
                         f"({name}=LO:HI)")
    if kind == "int":
        lo, hi = max(1, int(math.floor(v / FACTOR))), max(int(v) + 1, int(math.ceil(v * FACTOR)))
        while hi > v and not _valid(params, name, hi):
            hi = int(v + (hi - v) // 2)
        while lo < v and not _valid(params, name, lo):
            lo = int(math.ceil(v - (v - lo) / 2))
        if lo >= hi:
            raise InputError(f"--space {name}: no valid range around {v}; give one")
        return Dim(name, "int", lo, hi, True)
    if 0.9 <= v < 1.0 and not _valid(params, name, 1.0):
        q = 1.0 - v
        return Dim(name, "float", q / FACTOR, min(FACTOR * q, 0.5), True, complement=True)
    lo, hi = v / FACTOR, v * FACTOR
    for _ in range(30):
        if _valid(params, name, hi):
            break
        hi = v + (hi - v) / 2
    for _ in range(30):
        if _valid(params, name, lo):
            break
        lo = v - (v - lo) / 2
    return Dim(name, "float", lo, hi, True)


def search_space(tracker: str, params: Any, specs: Optional[list[str]] = None) -> list[Dim]:
    """The searched parameters of ``tracker`` starting from ``params``: ``specs`` (``--space``)
    when given, else the tracker class's ``tune_space``, else :data:`DEFAULT_SPACES`, else
    every positive float parameter.  A leaf name whose fields hold different values is split
    into its dotted names (each then keeps its own value)."""
    from pfscope.trackers.api import tracker_info
    from pfscope.trackers.params import leaves

    if specs:
        entries = [parse_space_spec(s) for s in specs]
    else:
        per_second = bool(getattr(getattr(params, "rate", None), "per_second", False))
        defaults = DEFAULT_SPACES_PER_SECOND if per_second else DEFAULT_SPACES
        declared = getattr(tracker_info(tracker).cls, "tune_space", None) \
            or defaults.get(tracker)
        if declared:
            entries = [parse_space_spec(s) for s in declared]
            # a preset may lack a name (another version of the tracker): search what exists
            entries = [(n, r) for n, r in entries if _targets(params, n)]
        else:
            entries = [(n, None) for n, _, v in leaves(params)
                       if isinstance(v, float) and math.isfinite(v) and v > 0]
    dims: list[Dim] = []
    for name, rng in entries:
        targets = _targets(params, name)
        if len(targets) > 1 and len({repr(v) for _, v in targets}) > 1:
            dims.extend(derive_dim(params, n, rng) for n, _ in targets)
        else:
            dims.append(derive_dim(params, name, rng))
    labels = [d.label for d in dims]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise InputError(f"--space: {', '.join(dup)} listed twice")
    if not dims:
        raise InputError(f"tracker {tracker!r}: no numeric parameter to search; give --space")
    return dims


# ------------------------------------------------------------------ one evaluation

@dataclass(frozen=True)
class SourceSpec:
    """How a worker process opens the source: a path, or the synthetic scene's config."""

    spec: Optional[str]
    fps: Optional[float] = None
    synthetic: Optional[tuple] = None       # SceneConfig fields as (name, value) pairs

    def open(self):
        from pfscope.trackers.data.sources import open_source

        cfg = None
        if self.synthetic is not None:
            from pfscope.trackers.data.synthetic import SceneConfig

            cfg = SceneConfig(**dict(self.synthetic))
        return open_source(self.spec, fps=self.fps, synthetic_config=cfg)


_SOURCES: dict = {}


def _cached_source(spec: SourceSpec):
    if spec not in _SOURCES:
        _SOURCES.clear()
        _SOURCES[spec] = spec.open()
    return _SOURCES[spec]


def blank_image_source(src):
    """``src`` yielding frames whose image is a blank of the right size (a read-only broadcast
    view: no memory, nothing decoded), for trackers that do not look at pixels.  None when
    the source's length is unknown or its timestamps are not ``(k - 1) / fps``."""
    from pfscope.trackers.data.sources import Source
    from pfscope.trackers.types import Frame, blank_image

    if src.length is None or src.kind not in ("mot", "synthetic", "images"):
        return None
    blank = blank_image(src.height, src.width)

    class _Blank(Source):
        def frames(self, limit=None, start=1):
            n = self.length if limit is None else min(start - 1 + limit, self.length)
            for k in range(max(1, start), n + 1):
                yield Frame(k, (k - 1) / self.fps, blank)

    return _Blank(name=src.name, fps=src.fps, length=src.length, width=src.width,
                  height=src.height, gt=src.gt, det=src.det, kind=src.kind,
                  location=src.location, extra=dict(src.extra))


@dataclass(frozen=True)
class EvalJob:
    """One configuration to score: run frames ``first..last`` once per seed, score each of
    ``ranges`` (inclusive frame pairs) separately."""

    source: SourceSpec
    tracker: str
    preset: Optional[str]
    options: tuple                     # ((name, value), ...) applied in order
    seeds: tuple
    first: int
    last: int
    ranges: tuple
    detector: Optional[str] = None
    min_score: float = float("-inf")
    convention: Optional[str] = None
    keep_scores: bool = False          # also return each range's full scores (combining)


def evaluate_config(job: EvalJob) -> dict:
    """Run ``job`` (in a worker process or here): never raises.  Returns ``{"scores": [per
    range: {key: [per seed]}], "seconds": s}`` or ``{"error": one line}``."""
    from pfscope.trackers.api import make_params, tracker_info
    from pfscope.trackers.data.motio import table_from_tracksets
    from pfscope.trackers.eval import evaluate
    from pfscope.trackers.pipeline import resolve_detector_name, run

    t0 = time.perf_counter()
    try:
        src = _cached_source(job.source)
        info = tracker_info(job.tracker)
        params = make_params(job.tracker, job.preset, dict(job.options))
        if not info.cls.needs_image:
            src = blank_image_source(src) or src
        scores: list[dict] = [{} for _ in job.ranges]
        for seed in job.seeds:
            trk = info.cls(params, rng=np.random.default_rng(seed))
            det = resolve_detector_name(src, job.detector) if trk.needs_detections else None
            det_opts = {"min_score": job.min_score} if det == "file" else {}
            res = run(src, {"t": trk}, frames=job.last - job.first + 1, start=job.first,
                      level=None, detector=det, detector_options=det_opts, score=False,
                      should_stop=stop_requested)
            if res.interrupted:
                return {"error": "stopped", "seconds": time.perf_counter() - t0}
            table = table_from_tracksets(res.rows["t"])
            for out, (a, b) in zip(scores, job.ranges):
                sc = evaluate(src.gt, table, frames=range(a, b + 1), convention=job.convention)
                for k in (*TABLE_KEYS, "convention"):
                    out.setdefault(k, []).append(sc.get(k))
                if job.keep_scores:      # every count, for combining sequences (combine())
                    out.setdefault("_scores", []).append(sc)
        return {"scores": scores, "seconds": time.perf_counter() - t0}
    except Exception as e:  # noqa: BLE001 - a trial's failure is reported, not raised
        msg = str(e).splitlines()[0] if str(e) else ""
        return {"error": f"{type(e).__name__}: {msg}"[:300], "seconds": time.perf_counter() - t0}


class _Runner:
    """Runs lists of :class:`EvalJob` in order, here (``jobs == 1``) or over the shared job
    runner's process pool (:mod:`pfscope.trackers.jobs`: a stop signal ends the whole study,
    raising :class:`~pfscope.trackers.jobs.Interrupted`, and no worker outlives it)."""

    def __init__(self, jobs: int):
        from .jobs import JobRunner

        self.runner = JobRunner(jobs).__enter__()

    def map(self, items: list) -> list:
        return self.runner.map(evaluate_config, items)

    def close(self) -> None:
        self.runner.__exit__(None, None, None)


# ------------------------------------------------------------------ the study

@dataclass
class TuneConfig:
    source: SourceSpec
    tracker: str
    frames: tuple                     # (first, last) tuned on
    holdout: Optional[tuple] = None   # (first, last) held out, or None
    preset: Optional[str] = None
    base_options: dict = field(default_factory=dict)   # --set / --params (applied first)
    trials: int = 30
    metric: str = "hota"
    seed: int = 0
    batch: int = 4
    jobs: int = 1
    trial_seeds: int = 1
    eval_seeds: int = 3
    space: Optional[list] = None
    detector: Optional[str] = None
    min_score: float = float("-inf")
    convention: Optional[str] = None
    #: further sequences tuned on together with ``source`` (the objective is then the
    #: COMBINED score: counts summed over the sequences, :func:`~.eval.combine`)
    more: tuple = ()
    name: str = ""                    # the first sequence's name (tables)

    def sequences(self) -> list["TuneSequence"]:
        """Every sequence tuned on: ``source`` (with ``frames``/``holdout``) then ``more``."""
        return [TuneSequence(self.source, self.frames, self.holdout, self.name),
                *self.more]


@dataclass(frozen=True)
class TuneSequence:
    """One sequence of a study over several: its source, tuned-on and held-out frames."""

    source: SourceSpec
    frames: tuple
    holdout: Optional[tuple] = None
    name: str = ""


@dataclass
class TuneResult:
    config: TuneConfig
    dims: list
    trials: list                       # dicts: number, value, params (labels), options, state
    best: dict                         # the best trial's dict
    start_value: float                 # objective of the starting parameters (trial 0)
    best_options: dict                 # option name → value (the searched ones)
    table: list = field(default_factory=list)   # rows: who, range label, role, means, stds
    source_name: str = ""
    convention: str = ""

    @property
    def best_value(self) -> float:
        return float(self.best["value"])


def _mean(values) -> float:
    vals = [float(v) for v in values if v is not None]
    return float(np.mean(vals)) if vals else float("nan")


def _objective(result: dict, key: str) -> Optional[float]:
    if "error" in result:
        return None
    v = _mean(result["scores"][0][key])
    return v if math.isfinite(v) else None


def _combined(results: list, key: str, ri: int = 0) -> Optional[float]:
    """``key`` of the sequences' results combined (counts summed per seed, as TrackEval's
    COMBINED row), mean over the seeds; None when any sequence failed."""
    from .eval import combine

    if any("error" in r for r in results):
        return None
    per_seed = zip(*(r["scores"][ri]["_scores"] for r in results))
    v = _mean(combine(list(seqs)).get(key) for seqs in per_seed)
    return v if math.isfinite(v) else None


def _first_error(results: list) -> dict:
    return next((r for r in results if "error" in r), results[0])


def _fmt_opts(options: dict) -> str:
    return " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                    for k, v in options.items())


def run_study(cfg: TuneConfig, *, log=None, on_trial=None) -> TuneResult:
    """Run the search (module docstring).  ``log(line)`` gets one line per trial;
    ``on_trial(trial dict, best dict)`` is called after each trial in order (the study
    recording)."""
    from pfscope.trackers.api import make_params

    optuna = import_optuna()
    from optuna.trial import TrialState

    key = METRICS[cfg.metric]
    try:
        base = make_params(cfg.tracker, cfg.preset, cfg.base_options)
    except ValueError as e:
        raise InputError(str(e)) from None
    dims = search_space(cfg.tracker, base, cfg.space)
    dists = {d.label: d.distribution() for d in dims}
    start_sample = {d.label: d.sample_of(_targets(base, d.name)[0][1]) for d in dims}
    enqueue = all(v is not None for v in start_sample.values())
    sampler = optuna.samplers.TPESampler(seed=cfg.seed, multivariate=True, constant_liar=True,
                                         n_startup_trials=max(4, min(10, cfg.trials // 3)))
    study = optuna.create_study(direction="maximize", sampler=sampler)
    if enqueue:
        study.enqueue_trial(start_sample)
    seeds = tuple(range(cfg.seed, cfg.seed + max(1, cfg.trial_seeds)))
    seqs = cfg.sequences()
    multi = len(seqs) > 1

    def jobs_for(options: dict) -> list[EvalJob]:
        return [EvalJob(q.source, cfg.tracker, cfg.preset,
                        tuple(cfg.base_options.items()) + tuple(options.items()), seeds,
                        q.frames[0], q.frames[1], (q.frames,), cfg.detector, cfg.min_score,
                        cfg.convention, keep_scores=multi) for q in seqs]

    def scored(results: list) -> tuple[Optional[float], dict]:
        """The trial's objective (combined over the sequences) and a result for its record."""
        if not multi:
            return _objective(results[0], key), results[0]
        r = _first_error(results)
        return _combined(results, key), {"seconds": sum(x.get("seconds", 0.0)
                                                        for x in results),
                                         **({"error": r["error"]} if "error" in r else {})}

    runner = _Runner(cfg.jobs)
    trials: list[dict] = []
    best: Optional[dict] = None
    start_value: Optional[float] = None
    t0 = time.perf_counter()
    try:
        if not enqueue:  # the starting values are outside the given ranges: score them apart
            start_value = scored(runner.map(jobs_for({})))[0]
        done = 0
        n_seq = len(seqs)
        while done < cfg.trials:
            batch = [study.ask(dists) for _ in range(min(cfg.batch, cfg.trials - done))]
            opts = [{d.name: d.value(t.params[d.label]) for d in dims} for t in batch]
            flat = runner.map([j for o in opts for j in jobs_for(o)])
            results = [flat[i * n_seq:(i + 1) * n_seq] for i in range(len(opts))]
            for t, o, rs in zip(batch, opts, results):
                value, r = scored(rs)
                if value is None:
                    study.tell(t, state=TrialState.FAIL)
                else:
                    study.tell(t, value)
                rec = {"number": t.number, "value": value, "params": dict(t.params),
                       "options": o, "seconds": r.get("seconds", 0.0),
                       "error": r.get("error"), "start": enqueue and t.number == 0}
                trials.append(rec)
                if rec["start"]:
                    start_value = value
                if value is not None and (best is None or value > best["value"]):
                    best = rec
                if log is not None:
                    what = (f"{key} {value:.4f}" if value is not None
                            else f"failed ({rec['error']})")
                    bst = f"best {best['value']:.4f} (trial {best['number']})" if best else \
                        "no success yet"
                    tag = " [starting values]" if rec["start"] else ""
                    log(f"tune [{t.number + 1:>{len(str(cfg.trials))}}/{cfg.trials}] {what}  "
                        f"{bst}  {rec['seconds']:.1f} s{tag}  {_fmt_opts(o)}")
                if on_trial is not None:
                    on_trial(rec, best)
            done += len(batch)
        if best is None:
            first = next((t["error"] for t in trials if t.get("error")), "no trial ran")
            raise InputError(f"every trial failed; the first: {first}")
        result = TuneResult(cfg, dims, trials, best,
                            start_value if start_value is not None else float("nan"),
                            dict(best["options"]))
        _final_table(result, runner)
    finally:
        runner.close()
    if log is not None:
        log(f"tune: {len(trials)} trials in {time.perf_counter() - t0:.0f} s")
    return result


def _ranges(cfg) -> list[tuple[str, tuple, str]]:
    """(role, frames, tag) of a sequence (``cfg``: a :class:`TuneConfig` or a
    :class:`TuneSequence`)."""
    out = [("tuned on", cfg.frames, "tuned")]
    if cfg.holdout is not None:
        out.append(("held out", cfg.holdout, "held"))
        lo = min(cfg.frames[0], cfg.holdout[0])
        hi = max(cfg.frames[1], cfg.holdout[1])
        out.append(("all (incl. tuned-on)", (lo, hi), "all"))
    return out


def _final_table(result: TuneResult, runner: _Runner) -> None:
    """Score the starting and the best parameters over tuned-on, held-out and all frames,
    ``eval_seeds`` seeds each (one run per seed covers every range); with several sequences,
    rows per sequence then COMBINED ones (counts summed over the sequences)."""
    cfg = result.config
    seqs = cfg.sequences()
    if len(seqs) > 1:
        _final_table_multi(result, runner, seqs)
        return
    ranges = _ranges(cfg)
    lo = min(r[1][0] for r in ranges)
    hi = max(r[1][1] for r in ranges)
    seeds = tuple(range(cfg.seed, cfg.seed + max(1, cfg.eval_seeds)))
    # the best trial may be the starting values (trial 0): then they are run once
    configs = ({},) if result.best.get("start") else ({}, result.best_options)
    jobs = [EvalJob(cfg.source, cfg.tracker, cfg.preset,
                    tuple(cfg.base_options.items()) + tuple(opts.items()), (s,), lo, hi,
                    tuple(r[1] for r in ranges), cfg.detector, cfg.min_score, cfg.convention)
            for opts in configs for s in seeds]
    out = runner.map(jobs)
    if len(configs) == 1:
        out = out + out
    for r in out:
        if "error" in r:
            raise InputError(f"scoring the parameters failed: {r['error']}")
    n = len(seeds)
    rows = []
    for ri, (role, (a, b), tag) in enumerate(ranges):
        for wi, who in enumerate(("start", "tuned")):
            per = out[wi * n:(wi + 1) * n]
            vals = {k: [p["scores"][ri][k][0] for p in per] for k in TABLE_KEYS}
            rows.append({"who": who, "frames": (a, b), "role": role, "tag": tag,
                         "mean": {k: _mean(v) for k, v in vals.items()},
                         "std": {k: float(np.std([float(x) for x in v])) for k, v in
                                 vals.items()},
                         "seeds": list(seeds)})
    result.table = rows
    result.convention = str(out[0]["scores"][0]["convention"][0])


def _final_table_multi(result: TuneResult, runner: _Runner, seqs: list) -> None:
    cfg = result.config
    seeds = tuple(range(cfg.seed, cfg.seed + max(1, cfg.eval_seeds)))
    configs = ({},) if result.best.get("start") else ({}, result.best_options)
    jobs, where = [], []
    for wi, opts in enumerate(configs):
        for qi, q in enumerate(seqs):
            ranges = _ranges(q)
            lo = min(r[1][0] for r in ranges)
            hi = max(r[1][1] for r in ranges)
            for s in seeds:
                jobs.append(EvalJob(q.source, cfg.tracker, cfg.preset,
                                    tuple(cfg.base_options.items()) + tuple(opts.items()),
                                    (s,), lo, hi, tuple(r[1] for r in ranges), cfg.detector,
                                    cfg.min_score, cfg.convention, keep_scores=True))
                where.append((wi, qi))
    out = runner.map(jobs)
    for r in out:
        if "error" in r:
            raise InputError(f"scoring the parameters failed: {r['error']}")
    whos = ("start", "tuned")
    by: dict = {}
    for (wi, qi), r in zip(where, out):
        by.setdefault((whos[wi], qi), []).append(r)
    if len(configs) == 1:
        by.update({("tuned", qi): v for (w, qi), v in list(by.items())})
    rows = []

    def row(who, seq, role, tag, frames, per_seed: list[dict]) -> dict:
        vals = {k: [p.get(k) for p in per_seed] for k in TABLE_KEYS}
        return {"who": who, "sequence": seq, "frames": frames, "role": role, "tag": tag,
                "mean": {k: _mean(v) for k, v in vals.items()},
                "std": {k: float(np.std([float(x) for x in v if x is not None]))
                        for k, v in vals.items()},
                "seeds": list(seeds)}

    from .eval import combine

    for qi, q in enumerate(seqs):
        for ri, (role, frames, tag) in enumerate(_ranges(q)):
            for who in whos:
                per = [p["scores"][ri]["_scores"][0] for p in by[(who, qi)]]
                rows.append(row(who, q.name, role, tag, frames, per))
    for ri, tag in enumerate(("tuned", "held", "all")):
        have = [qi for qi, q in enumerate(seqs) if len(_ranges(q)) > ri]
        if len(have) != len(seqs):
            break          # a sequence without held-out frames: no combined held-out row
        role = _ranges(seqs[0])[ri][0]
        for who in whos:
            per = [combine([by[(who, qi)][si]["scores"][ri]["_scores"][0] for qi in have])
                   for si in range(len(seeds))]
            rows.append(row(who, "COMBINED", role, tag, None, per))
    result.table = rows
    result.convention = str(out[0]["scores"][0]["convention"][0])


def _format_table_multi(result: TuneResult) -> str:
    cfg = result.config
    seeds = result.table[0]["seeds"] if result.table else []
    width = max(len("COMBINED"), *(len(r["sequence"]) for r in result.table))
    head = (f"{'sequence':<{width}} {'params':<6} {'frames':<10} {'':<21}"
            + " ".join(f"{k:>14}" for k in TABLE_KEYS[:3])
            + " ".join(f"{k:>7}" for k in TABLE_KEYS[3:]))
    lines = [f"scores, {result.convention.upper()} convention, mean ± std over tracker seeds "
             f"{', '.join(map(str, seeds))} (FP/FN/IDSW: mean); COMBINED sums the counts over "
             f"the {len(cfg.sequences())} sequences (the objective):", head]
    for r in result.table:
        m, s = r["mean"], r["std"]
        cells = " ".join(f"{m[k]:>7.3f} ±{s[k]:.3f}".rjust(14) for k in TABLE_KEYS[:3])
        cells += " ".join(f"{m[k]:>7.0f}" for k in TABLE_KEYS[3:])
        fr = "" if r["frames"] is None else f"{r['frames'][0]}-{r['frames'][1]}"
        lines.append(f"{r['sequence']:<{width}} {r['who']:<6} {fr:<10} {r['role']:<21}{cells}")
    lines.append("note: the parameters were chosen on the tuned-on frames of every sequence "
                 "(" + ", ".join(f"{q.name} {q.frames[0]}-{q.frames[1]}"
                                 for q in cfg.sequences())
                 + "): scores there overstate what to expect; the held-out rows do not.")
    return "\n".join(lines)


def format_table(result: TuneResult) -> str:
    if len(result.config.sequences()) > 1:
        return _format_table_multi(result)
    cfg = result.config
    seeds = result.table[0]["seeds"] if result.table else []
    head = (f"{'params':<8} {'frames':<10} {'':<21}" + " ".join(f"{k:>14}" for k in TABLE_KEYS[:3])
            + " ".join(f"{k:>7}" for k in TABLE_KEYS[3:]))
    lines = [f"scores, {result.convention.upper()} convention, mean ± std over tracker seeds "
             f"{', '.join(map(str, seeds))} (FP/FN/IDSW: mean):", head]
    for r in result.table:
        m, s = r["mean"], r["std"]
        who = "start" if r["who"] == "start" else "tuned"
        cells = " ".join(f"{m[k]:>7.3f} ±{s[k]:.3f}".rjust(14) for k in TABLE_KEYS[:3])
        cells += " ".join(f"{m[k]:>7.0f}" for k in TABLE_KEYS[3:])
        lines.append(f"{who:<8} {r['frames'][0]}-{r['frames'][1]:<{9 - len(str(r['frames'][0]))}}"
                     f" {r['role']:<21}{cells}")
    tuned = f"{cfg.frames[0]}-{cfg.frames[1]}"
    lines.append(f"note: the parameters were chosen on frames {tuned}: scores there (and on "
                 f"'all') overstate what to expect; "
                 + (f"frames {cfg.holdout[0]}-{cfg.holdout[1]} are held out."
                    if cfg.holdout else "there are no held-out frames, so every score above "
                                        "is on tuned-on frames."))
    lines.append("      each row is scored from one run over all the frames above (as `pfscope "
                 "record` then `pfscope eval --frames`); the search ran the tuned-on frames "
                 "alone, so a tracker that reports with a lag can score them a little "
                 "differently there.")
    return "\n".join(lines)


def tune_info(result: TuneResult, source_name: str) -> dict:
    """The ``[tune]`` table of the parameters file."""
    import optuna

    cfg = result.config
    info: dict = {
        "sequence": source_name, "tracker": cfg.tracker, "metric": METRICS[cfg.metric],
        "tuned_on_frames": f"{cfg.frames[0]}:{cfg.frames[1]}",
        "held_out_frames": f"{cfg.holdout[0]}:{cfg.holdout[1]}" if cfg.holdout else "none",
        "trials": len(result.trials), "seed": cfg.seed, "batch": cfg.batch,
        "trial_seeds": cfg.trial_seeds, "sampler": f"optuna {optuna.__version__} TPESampler",
        "best_trial": result.best["number"],
        "objective_tuned_on": round(result.best_value, 6),
        "objective_start_tuned_on": round(result.start_value, 6),
        "searched": [d.describe() for d in result.dims],
    }
    scores: dict = {}
    names = {"tuned": "tuned_on", "held": "held_out", "all": "all_frames"}
    seqs = cfg.sequences()
    if len(seqs) > 1:
        info["sequences"] = [q.name for q in seqs]
        info["tuned_on_frames"] = [f"{q.frames[0]}:{q.frames[1]}" for q in seqs]
        info["held_out_frames"] = [f"{q.holdout[0]}:{q.holdout[1]}" if q.holdout else "none"
                                   for q in seqs]
    for r in result.table:
        cell = {**({"frames": f"{r['frames'][0]}:{r['frames'][1]}"} if r["frames"] else {}),
                **{k: round(v, 6) for k, v in r["mean"].items()}}
        if len(seqs) > 1:      # [tune.scores.<who>.<sequence>.<range>]
            scores.setdefault(r["who"], {}).setdefault(r["sequence"], {})[names[r["tag"]]] = cell
        else:
            scores.setdefault(r["who"], {})[names[r["tag"]]] = cell
    info["eval_seeds"] = result.table[0]["seeds"] if result.table else []
    info["convention"] = result.convention
    info["scores"] = scores     # [tune.scores.start.held_out] ...: mean over eval_seeds
    return info


__all__ = ["Dim", "DEFAULT_SPACES", "DEFAULT_SPACES_PER_SECOND", "METRICS", "TABLE_KEYS", "SourceSpec",
           "TuneSequence",
           "EvalJob", "TuneConfig", "TuneResult", "search_space", "derive_dim",
           "parse_space_spec", "evaluate_config", "run_study", "format_table", "tune_info",
           "blank_image_source", "import_optuna"]
