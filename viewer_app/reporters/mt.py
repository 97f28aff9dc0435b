"""MT's views (maggio2007's baseline): the association graph on the raw detections."""

from .base import TrackerLayout

LAYOUT = TrackerLayout(
    views=(("Association", ("assoc/**", "tracks/trails")), ("Tracks", ("tracks/**",))),
    plots=(("Counts", ("tracks/count", "detections/count", "assoc/**")),
           ("Step ms", ("timing/**",))),
)
