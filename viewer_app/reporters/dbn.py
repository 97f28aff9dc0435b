"""DBN-PHD's views (feng2015), also used by its no-DBN baseline ``phd-bgsub``: the foreground
mask and the blobs the DBN accepted or rejected (with their scores), the per-particle DBN score,
the clouds before and after the update, Algorithm 3's N̂_k against the true count, K-means
clusters and the association.  To see why a noise blob was suppressed: the "Blobs" tab shows it
as a grey "rejected" box labelled with its DBN probability, the "DBN score" tab shows the dark
particles around it, "Update" shows how little mass it won (``won``), and the text log has one
line per rejected blob."""

from .base import TrackerLayout

LAYOUT = TrackerLayout(
    views=(("Tracks", ("tracks/**",)),
           ("Foreground", ("dbn/foreground",)),
           ("Blobs", ("dbn/blobs/**",)),  # no tracks (nor their miss marks) over the blobs
           ("DBN score", ("dbn/particles/score", "dbn/blobs/**")),
           # the cloud after the update only: the one before (equal weights, all teal) drawn
           # with it covered it ("All stages" still shows both)
           ("Update", ("dbn/particles/after", "dbn/update/**")),
           # the survivors by weight, the newborn in white, the blobs that spawned them
           ("Birth", ("dbn/particles/predicted", "dbn/particles/birth", "dbn/blobs/accepted")),
           ("Resampled", ("dbn/particles/resampled", "tracks/**")),
           ("Clusters", ("dbn/clusters/**",)),
           ("Association", ("assoc/**", "tracks/trails"))),
    notes=(("Tracks", "confirmed tracks and their errors"),
           ("Foreground", "the background-subtraction mask"),
           ("Blobs", "blobs the DBN accepted (cyan, as classifier hits) and rejected (dark grey)"),
           ("DBN score", "each scored particle's DBN probability, viridis 0 to 1 (not a rank)"),
           ("Update", "the cloud after the update, colour = weight rank, blobs with the mass "
                      "each won"),
           ("Birth", "survivors by predicted weight, newborn particles pink, accepted blobs"),
           ("Resampled", "the resampled cloud (equal weights, teal) and the tracks"),
           ("Clusters", "K-means clusters in the colour of the track that took them"),
           ("Association", "vertices, chosen edges with their gain, candidate edges, trails")),
    plots=(("N̂_k vs true count", ("dbn/n_hat", "metrics/cardinality/true", "tracks/count")),
           ("Blobs", ("dbn/blobs/count", "dbn/blobs/rejected", "dbn/clusters/kept")),
           ("Particles", ("dbn/particles/count", "dbn/birth/count", "dbn/particles/scored")),
           ("Foreground", ("dbn/foreground/fraction",)),
           ("Step ms", ("timing/**",))),
)
