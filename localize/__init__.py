"""indoormap localizer: particle filter on map bundles (in progress)."""
