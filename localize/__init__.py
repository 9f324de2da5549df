"""indoormap localizer: particle filter on map bundles, its baselines and a multi-user engine
(numpy and pyarrow only; docs/localize.md)."""
