"""PHD-MT (maggio2007): SMC-PHD filter on detections (§2, :mod:`.filter`), modified K-means
peak extraction (§3, :mod:`.clustering`), graph-matching data association (§3) and the
PHD-MT / MT trackers that tie them together."""
