"""Shared foundation of factory: the error hierarchy, atomic output files and the MCAP log.

The domain packages (:mod:`cadcam`, :mod:`robotprog`, :mod:`vision`) import from here;
nothing here imports them or the CLI.
"""

__version__ = "0.1.0"
