"""Online perspective prior on the parents' window scale (ours; jung2013 §2.1 draws the scale
"randomly" with no prior).

A camera looking down on a ground plane sees a person ``h`` px tall whose feet are at image row
``y_f`` with ``h ≈ a (y_f − y_horizon)``: height is linear in the foot row, hence also linear in
the box's centre row ``y_c = y_f − h/2`` (``h = (y_c − y_horizon) / (1/a − 1/2)``).  So the
prior is ``log h ~ N(log(α + β y_c), σ²)`` with ``α, β, σ`` **estimated online from the video**:
every classifier-verified box of a confirmed track (its parent's best verification hit, and the
box at confirmation) is one sample ``(y_c, h)``.  Nothing is scene-specific: before
``min_samples`` samples spread over ``min_spread`` of the image height have arrived, or when the
fit is not usable (a non-positive height anywhere in the image, a residual spread ≥
``sigma_max``), :meth:`ScalePrior.ready` is False and the parents keep the flat log-uniform draw.

Only objects that moved teach the prior: a track's samples (``key`` = its id) are held back until
its box centre has travelled ``min_travel`` × its height from where it was first seen, and are
then all added.  A static false positive (a building edge or a window that the person classifier
scores high, confirmed and then held by its own verification hits) never moves, so it cannot make
the prior ready as a constant height at its size: one object cannot define the camera's
height-vs-row law (that failure starved the search for the real people of whole clips).  People
walk, so they are counted after a few strides; one standing still for the whole clip is not, and
the parents keep the flat draw until someone moves.  ``min_travel`` = 0.25: a static object's
boxes jitter with the classifier's window grid (stride 8 px at the window's scale = h/12 of
the person box), by ~2 strides (measured 0.17-0.18 h over PETS09 clips); 0.25 h is 3 strides.

When the samples do not yet spread over ``min_spread`` of the image height (people all at one
depth, a close street camera, the first people of a clip) the fit falls back to a constant
height (``β = 0``, ``α`` the weighted mean height): the scale *range* is then still learnt from
the scene, only its slope waits for people at other rows.

Estimator: exponentially forgetting weighted least squares (``forget`` per sample) of ``h`` on
``(1, y_c)``, i.e. sufficient statistics ``Σw, Σw y, Σw y², Σw h, Σw y h`` decayed by ``forget``
at each new sample, so the prior follows a slow change (a zooming camera) but one bad sample
cannot move it much.  The spread ``σ`` is the weighted RMS of ``log(h / ĥ(y))``, floored at
``sigma_min`` (the classifier tolerates ~±10 % of scale, so a narrower draw gains nothing).

:func:`draw` mixes the prior with the flat draw: a fraction ``mix`` of parents draw from the
prior at their row, the rest log-uniformly (exploration: people off the plane, a wrong fit).
"""

from __future__ import annotations

import numpy as np


class ScalePrior:
    """Online fit of person height vs image row (module docstring)."""

    def __init__(self, height: int, *, forget: float = 0.995, min_samples: int = 20,
                 min_spread: float = 0.15, sigma_min: float = 0.08, sigma_max: float = 0.5,
                 min_travel: float = 0.25, max_pending: int = 64):
        if not (0 < forget <= 1 and min_samples >= 2 and 0 < sigma_min <= sigma_max
                and min_travel >= 0 and max_pending >= 1):
            raise ValueError("scale prior: need 0 < forget <= 1, min_samples >= 2, "
                             "0 < sigma_min <= sigma_max, min_travel >= 0, max_pending >= 1")
        self.height = float(height)
        self.forget, self.min_samples = float(forget), int(min_samples)
        self.min_spread, self.sigma_min, self.sigma_max = float(min_spread), float(sigma_min), \
            float(sigma_max)
        self.S = np.zeros(5)        # Σw, Σw y, Σw y², Σw h, Σw y h (y scaled by the height)
        self.R = np.zeros(3)        # Σw, Σw r, Σw r² of log residuals against the fit then
        self.n = 0
        self._ymin, self._ymax = np.inf, -np.inf
        self.min_travel, self.max_pending = float(min_travel), int(max_pending)
        # per key (track id): [first centre x, y, released?, held samples]
        self._keys: dict[int, list] = {}

    def add(self, boxes: np.ndarray, keys=None) -> None:
        """Add person boxes ``(x, y, w, h)`` (N, 4) as samples ``(centre row, height)``.

        ``keys`` (N track ids, optional): the samples of a key are held until its box centre has
        moved ``min_travel`` × its height from its first sample (module docstring); without
        keys every box is a sample at once."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        if keys is None:
            self._fit(b)
            return
        for box, k in zip(b, np.asarray(keys).reshape(-1).tolist()):
            cx, cy = box[0] + box[2] / 2, box[1] + box[3] / 2
            st = self._keys.get(k)
            if st is None:
                st = self._keys[k] = [cx, cy, False, []]
            if st[2]:
                self._fit(box[None])
                continue
            st[3].append(box)
            if len(st[3]) > self.max_pending:
                del st[3][0]
            if np.hypot(cx - st[0], cy - st[1]) >= self.min_travel * box[3]:
                st[2] = True
                self._fit(np.array(st[3]))
                st[3] = []

    def _fit(self, b: np.ndarray) -> None:
        for x, y, w, h in b:
            if not (h > 1 and np.isfinite(y)):
                continue
            yc = (y + h / 2) / self.height
            if self.n >= 2:  # residual against the fit before this sample (honest spread)
                ab = self.coef()
                if ab is not None:
                    pred = ab[0] + ab[1] * yc
                    if pred > 1:
                        r = np.log(h / pred)
                        self.R = self.forget * self.R + np.array([1.0, r, r * r])
            self.S = self.forget * self.S + np.array([1.0, yc, yc * yc, h, yc * h])
            self.n += 1
            self._ymin, self._ymax = min(self._ymin, yc), max(self._ymax, yc)

    def coef(self) -> np.ndarray | None:
        """``(α, β)`` of ``h = α + β y_c / H``, or None (no sample); ``β = 0`` while the samples
        span less than ``min_spread`` of the image height (module docstring)."""
        sw, sy, syy, sh, syh = self.S
        if sw <= 0:
            return None
        det = sw * syy - sy * sy
        if self._ymax - self._ymin < self.min_spread or det <= 1e-9 * max(sw * syy, 1e-12):
            return np.array([sh / sw, 0.0])
        beta = (sw * syh - sy * sh) / det
        alpha = (sh - beta * sy) / sw
        return np.array([alpha, beta])

    @property
    def sigma(self) -> float:
        """Spread of ``log h`` around the fit (floored at ``sigma_min``)."""
        w, s1, s2 = self.R
        if w <= 0:
            return self.sigma_max
        var = max(s2 / w - (s1 / w) ** 2, 0.0) + (s1 / w) ** 2  # RMS: bias counts too
        return max(float(np.sqrt(var)), self.sigma_min)

    def ready(self) -> bool:
        """Enough samples and a fit that is positive over the image."""
        if self.n < self.min_samples:
            return False
        ab = self.coef()
        if ab is None or min(ab[0], ab[0] + ab[1]) <= 1.0:
            return False
        return self.sigma < self.sigma_max

    def mean_height(self, y_centre: np.ndarray) -> np.ndarray:
        """Expected person height (px) for centre rows ``y_centre`` (px); needs :meth:`ready`."""
        ab = self.coef()
        assert ab is not None
        return ab[0] + ab[1] * np.asarray(y_centre, dtype=np.float64) / self.height

    def draw(self, y_centre: np.ndarray, lo: float, hi: float, mix: float,
             rng: np.random.Generator) -> np.ndarray:
        """Heights for parents at rows ``y_centre``: a fraction ``mix`` from the prior
        (log-normal around :meth:`mean_height`, clipped to ``[lo, hi]``), the rest log-uniform in
        ``[lo, hi]``; all log-uniform while not :meth:`ready`."""
        y = np.asarray(y_centre, dtype=np.float64).reshape(-1)
        n = len(y)
        flat = np.exp(rng.uniform(np.log(lo), np.log(hi), n))
        if not self.ready() or mix <= 0:
            return flat
        mu = np.log(np.maximum(self.mean_height(y), 1.0))
        prior = np.exp(mu + rng.normal(0.0, self.sigma, n))
        use = rng.random(n) < mix
        return np.where(use, np.clip(prior, lo, hi), flat)

    def bounds(self, lo: float, hi: float, margin: float = 2.0) -> tuple[float, float]:
        """The flat draw's range once the prior is :meth:`ready`: the learnt heights over the
        image rows widened by ``margin`` either way (people at depths not seen yet are still
        found), inside ``[lo, hi]``; ``(lo, hi)`` while not ready."""
        if not self.ready():
            return lo, hi
        h = self.mean_height(np.array([0.0, self.height]))
        a = float(np.clip(h.min() / margin, lo, hi))
        b = float(np.clip(h.max() * margin, lo, hi))
        return (a, b) if b > a else (lo, hi)

    def describe(self) -> str:
        if not self.ready():
            return f"scale prior: not ready ({self.n} samples)"
        a, b = self.coef()  # type: ignore[misc]
        return (f"scale prior: h = {a:.1f} + {b:.1f} * y/H px, sigma {self.sigma:.3f} "
                f"({self.n} samples)")


__all__ = ["ScalePrior"]
