"""PHD-MT's views (maggio2007): particles, birth & update, K-means clusters, association."""

from .base import TrackerLayout

LAYOUT = TrackerLayout(
    views=(("Tracks", ("tracks/**",)),
           ("Particles", ("phd/particles/updated", "tracks/**")),
           ("Birth & update", ("phd/particles/birth", "phd/birth/**", "phd/update/**")),
           ("Clusters", ("phd/clusters/**",)),
           ("Association", ("assoc/**", "tracks/**"))),
    plots=(("PHD mass", ("phd/mass", "phd/clusters/kept", "tracks/count", "detections/count")),
           ("Particles", ("phd/particles/count", "phd/birth/count")),
           ("Step ms", ("timing/**",))),
)
