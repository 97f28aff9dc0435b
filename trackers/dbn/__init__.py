"""DBN-PHD (feng2015): codebook background subtraction, colour + HOG integral-histogram
features, a torch RBM/DBN particle score, and the particle PHD filter that uses it.

torch is imported only by :mod:`.model` (and lazily by the modules that need a model), so
importing this package — or the tracker registry — never loads torch.
"""
