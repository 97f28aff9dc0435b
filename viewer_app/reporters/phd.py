"""PHD-MT's views (maggio2007): the weighted cloud after the update, the births among the
survivors, the K-means clusters in the colour of the track that took them, the association
graph with its gains."""

from .base import TrackerLayout

LAYOUT = TrackerLayout(
    # the update: every particle by weight, the detections with the mass each won, the tracks
    views=(("Tracks", ("tracks/**",)),
           ("Particles", ("phd/particles/updated", "phd/update/**", "tracks/**")),
           # before the update: the survivors by (predicted) weight, the newborn in white
           # around the detections that spawned them (labels: J born, M mass near)
           ("Birth", ("phd/particles/predicted", "phd/particles/birth", "phd/birth/**")),
           # the resampled cloud by cluster: a kept cluster in its track's colour, a kept
           # cluster no confirmed track took neutral grey, dropped clusters dark grey
           ("Clusters", ("phd/clusters/**",)),
           # the graph: this frame's vertices (thin, in their track's colour, tentative tracks
           # too), the chosen edges with their gain log f, candidate edges grey, recent trails
           ("Association", ("assoc/**", "tracks/trails"))),
    notes=(("Tracks", "confirmed tracks (thick, id labels, trails) and their errors"),
           ("Particles", "the cloud after the update, colour = weight rank; detections with the "
                         "mass each won; the tracks"),
           ("Birth", "survivors by predicted weight, newborn particles pink, the detections "
                     "that spawned them"),
           ("Clusters", "K-means clusters: kept ones in the colour of the track that took "
                        "them, untaken light grey, dropped dark grey"),
           ("Association", "this frame's vertices, chosen edges labelled with their gain "
                           "log f, candidate edges grey, trails")),
    plots=(("PHD mass", ("phd/mass", "phd/clusters/kept", "tracks/count", "detections/count")),
           ("Particles", ("phd/particles/count", "phd/birth/count")),
           # the camera motion followed (rate.camera_motion): shift in px, scale (1: still)
           ("Camera", ("phd/camera/shift", "phd/camera/scale")),
           ("Step ms", ("timing/**",))),
)
