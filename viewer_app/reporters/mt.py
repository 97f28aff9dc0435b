"""MT's views (maggio2007's baseline): the association graph on the raw detections."""

from .base import TrackerLayout

LAYOUT = TrackerLayout(
    views=(("Association", ("assoc/**", "tracks/trails")), ("Tracks", ("tracks/**",))),
    notes=(("Association", "vertices (the detections), chosen edges labelled with their "
                           "gain log f, candidate edges grey, trails"),
           ("Tracks", "confirmed tracks (thick, id labels, trails) and their errors")),
    plots=(("Counts", ("tracks/count", "detections/count", "assoc/**")),
           ("Step ms", ("timing/**",))),
)
