"""pfscope app: the CLI, the Rerun observer, blueprints and recording files.

This package holds the project's only ``import rerun``.
"""
