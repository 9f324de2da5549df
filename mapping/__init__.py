"""indoormap mapping stage: floor plans, levelling, rasters, fingerprints, bundles, registry.

``mapping.load_bundle`` / ``mapping.MapBundle`` are the bundle reader shared with the localizer
(:mod:`localize.bundle`, numpy-only).
"""

from localize.bundle import Grid, MapBundle, load_bundle

__all__ = ["Grid", "MapBundle", "load_bundle"]
