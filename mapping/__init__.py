"""indoormap mapping stage: floor plans, rasters, fingerprints, bundles (in progress)."""
