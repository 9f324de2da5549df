"""Errors of the fingerprint stage (a branch of :class:`survey.errors.IndoormapError`)."""

from __future__ import annotations

from survey.errors import IndoormapError


class FingerprintError(IndoormapError, ValueError):
    """Radio rows or fingerprint tables that cannot be used: missing columns, RSSI out of
    range, no positioned scans, unknown device model, inconsistent stored tables."""


__all__ = ["FingerprintError"]
