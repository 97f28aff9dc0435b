"""pfscope engine: particle-filter multi-target trackers, data sources, detectors and metrics.

The engine never imports rerun: trackers report their stages to an
:class:`trackers.observer.Observer`, and ``viewer_app`` turns that into a recording.
"""

__version__ = "0.2.0"
