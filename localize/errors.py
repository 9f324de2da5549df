"""Errors of the localizer (a branch of :class:`survey.errors.IndoormapError`)."""

from __future__ import annotations

from collections.abc import Iterable

from survey.errors import IndoormapError


class LocalizationError(IndoormapError, ValueError):
    """A walk cannot be localized on a bundle: no steps, no magnetometer, unknown floor, a
    bundle of another site, bad filter parameters or weights."""


class TickRefused(LocalizationError):
    """A multi-user tick refused for some of its users, before anyone moved: ``user_ids``
    names every user the failing check refused (the message shows the first reason), so that
    a server can drop them and tick the others again (it had to parse the text, one user a
    retry). The checks run in turn (compass, fixes off the map, unknown ids, step times, fix
    times): users refused for another kind of problem are named by the next attempt."""

    def __init__(self, message: str, user_ids: Iterable[int]) -> None:
        super().__init__(message)
        self.user_ids = [int(u) for u in user_ids]

    def __reduce__(self) -> tuple[type, tuple[str, list[int]]]:
        return (TickRefused, (self.args[0], self.user_ids))


__all__ = ["LocalizationError", "TickRefused"]
