"""Exception hierarchy of indoormap: one root, one subclass per domain.

Every error a user can trigger with bad input is an :class:`IndoormapError`; anything else that
escapes is a bug. Subclasses also inherit the closest builtin so that generic handlers work.
"""

from __future__ import annotations


class IndoormapError(Exception):
    """Root of every error indoormap raises on purpose."""


def at_path(path: object, text: str) -> str:
    """``"PATH: text"``, or ``text`` alone when it starts by naming ``path`` already
    (``"PATH: ..."``, ``"PATH:12: ..."``, ``"PATH (feature 0): ..."``), so a message names
    its file once. A longer path that starts with the same characters (``out/F10`` for
    ``out/F1``) is not ``path``."""
    p = str(path)
    if text.startswith(p + ":") or text.startswith(p + " ("):
        return text
    return f"{p}: {text}"


def require_type(value: object, expected: type, what: str, hint: str) -> None:
    """Refuse ``value`` unless it is an ``expected``: a :class:`TypeError` naming ``what`` was
    given and ``hint``, how to get the right thing (a path where a parsed trace belongs is the
    usual slip; without the check it fails deep inside with an attribute error)."""
    if not isinstance(value, expected):
        raise TypeError(f"{what}: a {expected.__name__} is needed ({hint}), "
                        f"not {type(value).__name__}")


class SurveyFormatError(IndoormapError, ValueError):
    """A survey file (trace, walk-line CSV, walk plan) does not follow its format.

    Attributes
    ----------
    path : str or None
        File the problem was found in.
    line : int or None
        1-based line number, when the problem is on one line.
    reason : str
        Short machine-friendly reason (``"field_count"``, ``"non_numeric"``, ...).
    """

    def __init__(self, message: str, *, path: str | None = None, line: int | None = None,
                 reason: str = "format") -> None:
        where = path or "<input>"
        if line is not None:
            where = f"{where}:{line}"
        super().__init__(f"{where}: {message}")
        self.message = message
        self.path = path
        self.line = line
        self.reason = reason

    def __reduce__(self):
        # rebuilt with its fields when it crosses a process (ingest workers), not from the
        # formatted text alone
        return (_survey_format_error, (type(self), self.message, self.path, self.line,
                                       self.reason))


def _survey_format_error(cls: type, message: str, path: str | None, line: int | None,
                         reason: str) -> SurveyFormatError:
    return cls(message, path=path, line=line, reason=reason)


class StoreError(IndoormapError):
    """The survey store is missing, locked, or inconsistent."""


class PublishError(IndoormapError, OSError):
    """An output could not be published (target exists without overwrite, I/O failure)."""


class SimulationError(IndoormapError, ValueError):
    """Simulator parameters are inconsistent."""


class ProcessingError(IndoormapError, ValueError):
    """A walk cannot be processed (no steps, no waypoints, missing streams, ...)."""


class BundleError(IndoormapError, ValueError):
    """A map bundle cannot be used: missing, wrong format or schema version, bad content."""


class BundleIntegrityError(BundleError):
    """A map bundle's content does not match its manifest (changed, missing or extra bytes)."""


class BundleReplaced(BundleError):
    """The folder a map bundle was loaded from now holds another bundle (rebuilt with
    ``--overwrite``): the loaded one is intact in memory; load the folder again for the new."""


class RegistryError(IndoormapError):
    """A bundle registry operation is refused (unknown version, silent rollback, ...)."""


class RollbackRefused(RegistryError):
    """Pointing a registry floor at an older version than its current one, without allowing
    a rollback. ``where`` is ``site/floor``, ``bundle_id`` the version refused; ``seq`` and
    ``current_seq`` are the two versions' sequence numbers;
    ``current_known`` is False when the pointer was unreadable and ``current_seq`` is the
    newest version's. ``current_text`` says which: ``the current #2``, or ``the newest #2
    (the current pointer is unreadable)``."""

    def __init__(self, where: str, bundle_id: str, *, seq: int, current_seq: int,
                 current_known: bool = True) -> None:
        self.where, self.bundle_id = where, bundle_id
        self.seq, self.current_seq, self.current_known = seq, current_seq, current_known
        self.current_text = (f"the current #{current_seq}" if current_known else
                             f"the newest #{current_seq} (the current pointer is unreadable)")
        super().__init__(f"{where}: version {bundle_id[:12]} (#{seq}) is older than "
                         f"{self.current_text}; rolling back needs allow_rollback=True")

    def __reduce__(self):
        # rebuilt with its fields when it crosses a process (a registry shared by a pool of
        # builders): the default passes the formatted text alone, which __init__ cannot take
        return (_rollback_refused, (type(self), self.where, self.bundle_id, self.seq,
                                    self.current_seq, self.current_known))


class WithdrawnVersion(RollbackRefused):
    """Publishing again a version that a rollback moved the current pointer back from (a
    nightly build of unchanged inputs makes the same bytes): making it current would undo
    the rollback without a word. ``seq`` is the withdrawn version's number, ``current_seq``
    the current one's."""

    def __init__(self, where: str, bundle_id: str, *, seq: int, current_seq: int,
                 current_known: bool = True) -> None:
        super().__init__(where, bundle_id, seq=seq, current_seq=current_seq,
                         current_known=current_known)
        self.args = (f"{where}: version {bundle_id[:12]} (#{seq}) was rolled back from (the "
                     f"current is #{current_seq}); making it current again needs set_current",)


def _rollback_refused(cls: type, where: str, bundle_id: str, seq: int, current_seq: int,
                      current_known: bool) -> RollbackRefused:
    return cls(where, bundle_id, seq=seq, current_seq=current_seq, current_known=current_known)
