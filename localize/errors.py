"""Errors of the localizer (a branch of :class:`survey.errors.IndoormapError`)."""

from __future__ import annotations

from survey.errors import IndoormapError


class LocalizationError(IndoormapError, ValueError):
    """A walk cannot be localized on a bundle: no steps, no magnetometer, unknown floor, a
    bundle of another site, bad filter parameters or weights."""


__all__ = ["LocalizationError"]
