"""DLPF's views (jung2013): the motion field and the parents (first layer), the classifier
windows and confirmation, the child clouds and MAP boxes (second layer)."""

from .base import TrackerLayout

LAYOUT = TrackerLayout(
    views=(("Tracks", ("tracks/**", "dlpf/children/map")),
           ("Motion", ("dlpf/motion/**", "dlpf/parents/predicted")),
           ("Parents", ("dlpf/parents/free", "dlpf/parents/owned", "dlpf/classify/hits")),
           ("Classifier", ("dlpf/classify/**", "dlpf/confirm/**")),
           ("Children", ("dlpf/children", "dlpf/children/map", "tracks/**"))),
    # hits (0-2 a frame) on their own axis, not under the hundreds of windows
    notes=(("Tracks", "tracks (thick) with their MAP boxes and errors"),
           ("Motion", "Lucas-Kanade motion magnitude (viridis, 0 transparent) and the parents "
                      "predicted on it, by weight"),
           ("Parents", "free parents (equal weights, teal), parents owned by a track in its "
                       "colour, classifier hits cyan"),
           ("Classifier", "scored windows thin grey, verification windows in track colours, "
                          "hits cyan, confirmation candidates"),
           ("Children", "each track's child cloud in its colour, MAP boxes, tracks")),
    plots=(("Windows / frame", ("dlpf/classify/windows",)),
           ("Hits / frame", ("dlpf/classify/hits", "dlpf/confirm/candidates")),
           ("Particles", ("dlpf/parents/free", "dlpf/children/count")),
           ("Tracks", ("dlpf/tracks", "tracks/count", "dlpf/confirm/candidates")),
           ("Bhattacharyya", ("dlpf/bhattacharyya/**",)),
           ("Scale prior (px)", ("dlpf/scale/**",)),
           ("Motion", ("dlpf/motion/mean", "dlpf/motion/magnitude/**")),
           ("Step ms", ("timing/**",))),
)
