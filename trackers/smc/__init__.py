"""Sequential Monte Carlo building blocks shared by the trackers.

- :mod:`.weights` — log-weight utilities (logsumexp normalisation, ESS) and :class:`ParticleSet`.
- :mod:`.resampling` — systematic, stratified, residual and multinomial resampling
  (explicit ``numpy.random.Generator``; mass-preserving :func:`resample`).

State-dimension-agnostic: motion models live next to their paper (``phd/motion.py`` for
maggio2007's size-aware model).
"""

from .resampling import SCHEMES, resample, resample_indices
from .weights import ParticleSet, ess, logsumexp, normalise, normalised_weights

__all__ = ["ParticleSet", "ess", "logsumexp", "normalise", "normalised_weights",
           "SCHEMES", "resample", "resample_indices"]
