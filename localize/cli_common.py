"""What the localizer's commands (``localize``, ``evaluate``, ``floor``, ``wifi-locate``)
share: finding trace files and walk plans, reading a walk with its warnings, reporting walks
that fail while the others go on, and options renamed for consistency whose old spellings
still work (:class:`AliasedOption`)."""

from __future__ import annotations

import re
import sys
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import click

from localize.errors import LocalizationError
from localize.floors import FLOOR_CHANGE, HEADER_DOUBT, LACKS_PHRASE, MODEL_LACKS

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import ArrayLike, NDArray

    from localize.bundle import MapBundle
    from localize.track import Track
    from survey.trace_format import Trace

__all__ = ["AliasedOption", "FloorChoices", "SeenWalks", "WalkFailures", "each_walk",
           "read_walk", "read_walks", "trace_files"]

T = TypeVar("T")


class AliasedOption(click.Option):
    """An option whose old spellings (``old_names``) are still accepted but left out of
    ``--help`` and of error messages, which name the current spelling only.

    Examples
    --------
    >>> @click.command()
    ... @click.option("--method", "--methods", "methods", cls=AliasedOption,
    ...               old_names=("--methods",))
    ... def cmd(methods):
    ...     click.echo(methods)
    >>> from click.testing import CliRunner
    >>> CliRunner().invoke(cmd, ["--methods", "pdr"]).output.strip()
    'pdr'
    >>> "--methods" in CliRunner().invoke(cmd, ["--help"]).output
    False
    """

    def __init__(self, *args, old_names: Sequence[str] = (), **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.old_names = tuple(old_names)
        unknown = [n for n in self.old_names if n not in self.opts]
        if unknown or len(self.old_names) >= len(self.opts):
            raise ValueError(f"old names {self.old_names} must be some of {self.opts}")

    def _current_only(self, method, ctx):
        saved = self.opts
        self.opts = [o for o in saved if o not in self.old_names]
        try:
            return method(ctx)
        finally:
            self.opts = saved

    def get_help_record(self, ctx: click.Context):
        return self._current_only(super().get_help_record, ctx)

    def get_error_hint(self, ctx: click.Context) -> str:
        return self._current_only(super().get_error_hint, ctx)


def trace_files(paths: tuple[str, ...], failures: WalkFailures) -> list[Path]:
    """The trace files (``.txt``, ``.txt.gz``) and walk plans (``.geojson``, indoormap's
    walk-line format) given or inside the given folders, as ``indoormap ingest`` finds them.
    A path that does not exist is reported to ``failures`` as a walk that failed, and the
    others go on.

    Raises
    ------
    click.UsageError
        None found, and no path was missing.
    """
    from survey.ingest import find_inputs

    present = []
    for p in paths:
        if Path(p).exists():
            present.append(p)
        else:
            failures.missing(p)
    traces, plans = find_inputs(present)
    files = traces + plans  # in ingest's order: one trace id, the same walk kept
    if not files and not failures.count:
        raise click.UsageError("no trace files (.txt, .txt.gz) or walk plans (.geojson) "
                               "found in the given paths")
    unique: dict[Path, Path] = {}
    for f in files:  # one file named twice (relative and absolute, or a folder and a file)
        unique.setdefault(f.resolve(), f)
    return list(unique.values())


def each_walk(files: list[Path], failures: WalkFailures,
              fn: Callable[[str, Trace], None]) -> int:
    """``fn(where, trace)`` for every walk of ``files`` (:func:`trace_files`): a trace file's
    walk (``where`` the file), or each walk of a walk plan (``where`` the plan and the walk's
    id). A file that cannot be read, and a walk ``fn`` fails on, are reported to
    ``failures`` and the others go on. Returns the number of walks (an unreadable file
    counts as one), for :meth:`WalkFailures.exit_if_any`."""
    total = 0
    for f in files:
        walks = failures.run(f, lambda f=f: read_walks(f))
        total += 1 if walks is None else len(walks)
        for where, walk in walks or []:  # a plan's walk that fails its checks fails alone
            failures.run(where, lambda where=where, walk=walk: fn(where, walk()))
    return total


def _indoormap_data(folder: Path) -> str | None:
    """``"map bundle"``, ``"registry floor folder"``, ``"survey store"`` or None: what
    indoormap keeps in ``folder``, by its own marker files (a ``manifest.json`` of another
    program is not a bundle)."""
    import json

    from localize.bundle import BUNDLE_FORMAT, MAX_MANIFEST_BYTES
    from survey.regular_files import read_regular

    def doc(name: str) -> dict:
        try:  # a small regular file (a FIFO named manifest.json is not waited on)
            d = json.loads(read_regular(folder / name, MAX_MANIFEST_BYTES))
        except (OSError, ValueError):
            return {}
        return d if isinstance(d, dict) else {}

    if doc("manifest.json").get("format") == BUNDLE_FORMAT:
        return "map bundle"
    if (folder / "CURRENT").is_file() and (folder / "history.json").is_file():
        return "registry floor folder"
    if "schema_version" in doc("store.json"):
        return "survey store"
    return None


def refuse_output_inside_data(out: Path, param_hint: str = "-o") -> None:
    """A usage error (naming the option ``param_hint``) when the output folder or file
    ``out`` is, or lies inside, a map bundle, a registry floor folder or a survey store:
    files written there made the bundle fail its checks ("not listed in the manifest"), and
    ``--overwrite`` replaced a store's ``catalog.parquet`` with a track."""
    p = out.resolve()
    for folder in (p, *p.parents):
        what = _indoormap_data(folder)
        if what:
            raise click.BadParameter(f"{out} is {'' if folder == p else 'inside '}the {what} "
                                     f"{folder}: write the results elsewhere",
                                     param_hint=param_hint)


def read_walks(path: Path) -> list[tuple[str, Callable[[], Trace]]]:
    """``(where, walk)`` of each walk in ``path``, ``walk()`` reading and checking its trace: a
    trace file's one walk (:func:`read_walk`, ``where`` the file), a walk-line sensor CSV's
    (:func:`survey.walkline.sensor_log_walk`), or a walk plan's walks (``where``:
    ``plan.geojson (walk ID)``), the plan read here, each walk's sensor log when asked and
    checked as :func:`read_walk` checks a trace, so that one walk's failure leaves the
    plan's others to run (and one walk's log is in memory at a time)."""
    from survey.walkline import plan_walks, sensor_log_walk

    def read(walk) -> Trace:
        logs = walk.log_bytes()  # not its identity: ingest's, to hash
        return _checked_walk(walk.parse(logs), Path(logs.source))

    if path.name.lower().endswith(".csv"):  # a walk-line sensor log alone: no ground truth
        return [(str(path), lambda: read(sensor_log_walk(path)))]
    if not path.name.endswith(".geojson"):
        return [(str(path), lambda: read_walk(path))]

    walks = plan_walks(path)
    ids = Counter(walk.walk_id for walk in walks)
    # a walk id twice in one plan: each is told apart by its feature (the second is refused)
    return [(f"{path} (walk {walk.walk_id}"
             + (f", feature {k})" if ids[walk.walk_id] > 1 else ")"),
             lambda walk=walk: read(walk)) for k, walk in enumerate(walks)]


def read_walk(path: Path) -> Trace:
    """The trace at ``path``; a warning names the file when lines had to be skipped (bad
    lines, a damaged compressed stream), as ``indoormap ingest`` reports them.

    Raises
    ------
    SurveyFormatError
        The file holds no sensor sample, waypoint or scan (empty, or not a trace file), or
        its scans or waypoints lie outside its samples' time span (clocks that differ).
    """
    from survey.trace_reader import read_trace

    return _checked_walk(read_trace(path), path)


def _checked_walk(trace: Trace, path: Path) -> Trace:
    """``trace`` (read from ``path``) unless its clocks differ; a warning names the file
    when lines had to be skipped."""
    from survey.errors import SurveyFormatError
    from survey.trace_format import bad_lines_summary

    mismatch = trace.clock_mismatch()
    if mismatch:
        raise SurveyFormatError(mismatch, path=str(path), reason="clock")
    r = trace.report
    if r.bad_total:
        # the messages name the file too ("path:12: reason"): said once, before them
        said = [re.sub(r"^(\d+): ", r"line \1: ", m[len(str(path)) + 1:].lstrip())
                if m.startswith(f"{path}:") else m for m in r.messages[:1]]
        click.echo(f"warning: {path}: {bad_lines_summary(r.bad, said)}", err=True)
    return trace


class TraceIds:
    """The trace ids of one run's walks: a second walk with an id already seen would replace
    the first one's outputs (``<trace_id>.parquet``), be merged with it in the scores, or
    print its rows under the same id; ``why`` says which (the end of the error)."""

    def __init__(self, why: str = "its outputs would replace the other's") -> None:
        self._first: dict[str, str | Path] = {}
        self._why = why

    def claim(self, trace_id: str, path: str | Path) -> None:
        """Note ``trace_id`` as ``path``'s (a file, or a walk of a walk plan); a
        LocalizationError if another file had it."""
        first = self._first.setdefault(trace_id, path)
        if first != path:  # another file: trace_files named each file once
            raise LocalizationError(f"{path}: trace id {trace_id} is also {first}'s in this "
                                    f"run; rename one ({self._why})")


class WalkFailures:
    """Walks that could not be read or localized: each is reported with its file and reason,
    and the walks after it still run."""

    def __init__(self) -> None:
        self.count = 0
        self.n_missing = 0  # paths given that do not exist (not among the files run)

    def missing(self, path: str | Path) -> None:
        """Report a walk path that does not exist."""
        self.count += 1
        self.n_missing += 1
        p = str(path)
        other = p[:-3] if p.endswith(".gz") else p + ".gz"  # walk.txt for walk.txt.gz
        hint = f" (there is {other})" if Path(other).is_file() else ""
        click.echo(f"error: {path}: no such file or folder{hint}", err=True)

    def run(self, where: str | Path, fn: Callable[[], T]) -> T | None:
        """``fn()``, or None after reporting an indoormap error (bad trace, no start, ...)
        under ``where`` (the file, and the method when one method failed)."""
        from survey.errors import IndoormapError, at_path

        try:
            return fn()
        except IndoormapError as err:
            self.count += 1
            click.echo(f"error: {at_path(where, str(err))}", err=True)
            return None

    def exit_if_any(self, total: int) -> None:
        """Say how many of ``total`` walks (the files run, besides the paths missing) failed
        and exit with status 1, if any did."""
        if self.count:
            click.echo(f"{self.count} failure(s) in {total + self.n_missing} walk(s)", err=True)
            sys.exit(1)


class SeenWalks:
    """Warns when a walk is localized on a bundle built from it: its track, and any error
    measured on it, is then better than an unseen walk's would be. The first
    :attr:`NAMED` such walks of a run are warned of one by one, the rest in one line by
    :meth:`finish` (localizing a survey folder on its own build named every walk, 97 lines
    for site1/F3)."""

    NAMED = 3

    def __init__(self, results: str = "its track (and any error measured on it) is") -> None:
        self.results = results  # what is better (wifi-locate makes fixes, not tracks)
        self.more: list[str] = []
        self._named = 0
        self.count = 0  # walks of the run the bundles were built from

    def check(self, bundle: MapBundle, trace_id: str) -> None:
        """Warn (or count, past the first :attr:`NAMED`) when ``bundle`` was built from walk
        ``trace_id``."""
        if trace_id not in bundle.source_walk_ids():
            return
        self.count += 1
        if self._named < self.NAMED:
            self._named += 1
            click.echo(f"warning: {trace_id} was used to build {bundle.path}: the map has seen "
                       f"it, so {self.results} better than an unseen walk's would be",
                       err=True)
        else:
            self.more.append(trace_id)

    def finish(self) -> None:
        """Say the walks not named yet, once (call at the end of the run)."""
        if self.more:
            shown = ", ".join(self.more[:5]) + (", ..." if len(self.more) > 5 else "")
            click.echo(f"warning: {len(self.more)} more walk(s) were used to build their "
                       f"bundle ({shown}): their results too are better than unseen walks' "
                       "would be", err=True)
            self.more = []


def waypoint_errors_quietly(track: Track, t_ms: ArrayLike, xy_m: ArrayLike
                            ) -> NDArray[np.float64]:
    """:func:`localize.evaluate.waypoint_errors` without its :class:`SeenWalkWarning`: the
    commands' :class:`SeenWalks` says that in its own words, once per walk. Waypoints it
    refuses (none near the track's time span) are the walk's failure, reported with it."""
    import warnings

    from localize.evaluate import SeenWalkWarning, waypoint_errors

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SeenWalkWarning)
        try:
            return waypoint_errors(track, t_ms, xy_m)
        except ValueError as err:
            raise LocalizationError(f"{track.trace_id}: {err}") from err


class FloorChoices:
    """Says on standard error, walk by walk, the floor a floor model chose
    (:meth:`localize.floors.SiteMaps.choose`'s ``how``): a note when a model chose, a warning
    when the Wi-Fi floor model contradicts the header's floor or when the model that chose
    lacks some of the floors given; nothing for a header's floor. The same lacking floors are
    warned of once per run (a folder with Wi-Fi on only some floors and no BLE model would
    repeat it for every walk); later walks' notes refer to it."""

    def __init__(self) -> None:
        self._lacks_warned: set[str] = set()

    def say(self, trace_id: str, bundle: MapBundle, how: str) -> None:
        """Say how walk ``trace_id`` was put on ``bundle``'s floor (``how``: the phrase of
        :meth:`~localize.floors.SiteMaps.choose`)."""
        floor = bundle.manifest.get("floor_name", "")
        lacks = LACKS_PHRASE.search(how)
        repeated = lacks is not None and lacks.group(0) in self._lacks_warned
        if repeated:
            how = how.replace(lacks.group(0), f"{MODEL_LACKS} {lacks.group(1)} (warned above)")
        elif lacks is not None:
            self._lacks_warned.add(lacks.group(0))
        if HEADER_DOUBT in how or FLOOR_CHANGE in how or (MODEL_LACKS in how
                                                          and not repeated):  # said, not overruled
            click.echo(f"warning: {trace_id}: floor {floor} by the {how}", err=True)
        elif "floor model" in how:
            click.echo(f"{trace_id}: floor {floor} by the {how}", err=True)
