"""DLPF — dual-layer particle filter (jung2013): parent particles resampled on Lucas–Kanade
motion run a pedestrian classifier on one window each; a confirmed person spawns child
particles that track it with HSV colour histograms.

- :mod:`.motion` — LK motion at the parents, eqs. (1), (6)–(8), masking of tracked regions;
- :mod:`.parents` — parent particles, eqs. (2)–(5), resampling, reset;
- :mod:`.scale` — online perspective prior on the parents' window scale (ours);
- :mod:`.classifier` — HOG + linear SVM on single windows (OpenCV's people SVM), blocks shared
  across windows on a pyramid;
- :mod:`.iksvm` — the paper's intersection-kernel SVM with Maji et al.'s lookup tables
  (``pfscope train-classifier``);
- :mod:`.confirm` — confirmation after 4 sequential detections (§2.2);
- :mod:`.children` — HSV histograms, Bhattacharyya distance, AR(2) child particles, eqs. (12)–(15);
- :mod:`.tracker` — :class:`~.tracker.DLPFTracker` (``--tracker dlpf``).
"""
