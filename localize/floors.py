"""Which floor bundle a walk runs on, and the checks that a walk fits a bundle.

A floor bundle answers for one floor. :class:`SiteMaps` holds the floor bundles of a site and
picks one per walk: by the walk's floor id (trace header), else by a floor model (an object
with ``floor_of(scan) -> floor id | None``, e.g. the site-level bundle's classifier once the
mapping stage writes one, or :meth:`KnnRadioPositioner.floor_of`), else it refuses.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Protocol

from localize.bundle import MapBundle
from localize.errors import LocalizationError
from localize.steps import RadioScan, StepSummaries

__all__ = ["FloorModel", "SiteMaps", "check_walk_fits"]


class FloorModel(Protocol):
    def floor_of(self, scan: RadioScan) -> str | None:
        """Floor id of a scan, or None when unsure."""


def check_walk_fits(bundle: MapBundle, steps: StepSummaries) -> None:
    """Refuse walks that cannot be localized on ``bundle``.

    Raises
    ------
    LocalizationError
        No steps; no magnetometer values (unless the caller runs a method without magnetic
        update, see ``require_magnetometer`` of :meth:`Localizer.run`); the walk's site or
        floor id differs from the bundle's.
    """
    where = steps.trace_id or "walk"
    if len(steps) == 0:
        raise LocalizationError(f"{where}: no steps detected, nothing to localize")
    if steps.site_id and bundle.site_id and steps.site_id != bundle.site_id:
        raise LocalizationError(f"{where}: recorded at site {steps.site_id}, but the bundle "
                                f"{bundle.path} is of site {bundle.site_id}")
    if steps.floor_id and bundle.floor_id and steps.floor_id != bundle.floor_id:
        name = f" ({steps.floor_name})" if steps.floor_name else ""
        raise LocalizationError(f"{where}: recorded on floor {steps.floor_id}{name}, but the "
                                f"bundle {bundle.path} is floor {bundle.floor_id} "
                                f"({bundle.manifest.get('floor_name', '')})")


class SiteMaps:
    """The floor bundles of one site.

    Parameters
    ----------
    bundles : iterable of MapBundle
        Floor bundles of one site (distinct floor ids).
    floor_model : FloorModel, optional
        Used when a walk carries no floor id.
    """

    def __init__(self, bundles: Iterable[MapBundle], floor_model: FloorModel | None = None):
        self.bundles: dict[str, MapBundle] = {}
        sites = set()
        for b in bundles:
            if b.grid is None:
                continue  # a site-level bundle: holds the floor model later, no rasters
            if b.floor_id in self.bundles:
                raise LocalizationError(f"two bundles for floor {b.floor_id}: "
                                        f"{self.bundles[b.floor_id].path} and {b.path}")
            self.bundles[b.floor_id] = b
            sites.add(b.site_id)
        if len(sites) > 1:
            raise LocalizationError(f"bundles of several sites given: {sorted(sites)}")
        if not self.bundles:
            raise LocalizationError("no floor bundle given")
        self.site_id = sites.pop()
        self.floor_model = floor_model
        self._by_name = {b.manifest.get("floor_name", ""): b for b in self.bundles.values()}

    @classmethod
    def open(cls, path: str | Path) -> SiteMaps:
        """The floor bundles at ``path``: one floor bundle, a folder of bundles (as
        ``indoormap build`` writes, with the site bundle ``_site`` whose floor model then
        picks the floor of walks that name none), or a registry's site or floor folder
        (``REG/<site>``, ``REG/<site>/<floor>``: their current versions).

        Raises
        ------
        LocalizationError
            Nothing there is a bundle; bundles of several sites or two of one floor.
        BundleError, RegistryError
            A damaged bundle or registry pointer (:func:`~localize.bundle.load_bundle`).
        """
        from localize.bundle import bundle_dirs, is_bundle_dir, load_bundle
        from localize.floor_classifier import FloorClassifier

        path = Path(path)
        subs = [load_bundle(path)] if is_bundle_dir(path) else [
            load_bundle(p) for p in bundle_dirs(path)]
        if not subs:
            raise LocalizationError(f"{path}: neither a bundle nor a folder of bundles (nor a "
                                    "registry's site folder)")
        site = [b for b in subs if b.manifest.get("kind") == "site"]
        floors = [b for b in subs if b.manifest.get("kind") != "site"]
        if not floors:
            raise LocalizationError(f"{path}: a site bundle only (floor model, device table); "
                                    "localizing needs floor bundles: give the folder "
                                    "`indoormap build` wrote, or one floor's bundle")
        model = FloorClassifier.from_bundle(site[0]) if site else None
        try:
            return cls(floors, floor_model=model)
        except LocalizationError as err:
            raise LocalizationError(f"{path}: {err}") from err

    def select(self, steps: StepSummaries) -> MapBundle:
        """The bundle of the walk's floor (see :meth:`select_for`)."""
        return self.select_for(steps.trace_id, steps.site_id, steps.floor_id,
                               steps.floor_name, steps.scans)

    def select_for(self, trace_id: str, site_id: str, floor_id: str, floor_name: str,
                   wifi_scans: Sequence[RadioScan | None] | None) -> MapBundle:
        """The bundle of a walk's floor from what its trace header says (empty strings when
        it says nothing) or, failing that, the site's floor model over its Wi-Fi scans.

        Raises
        ------
        LocalizationError
            Another site, a floor without a bundle, or no way to tell the floor.
        """
        where = trace_id or "walk"
        if site_id and site_id != self.site_id:
            raise LocalizationError(f"{where}: recorded at site {site_id}, the bundles "
                                    f"are of site {self.site_id}")
        if floor_id:
            if floor_id in self.bundles:
                return self.bundles[floor_id]
            raise LocalizationError(f"{where}: unknown floor {floor_id} "
                                    f"({floor_name or '?'}); bundles exist for "
                                    f"{sorted(self._by_name)}")
        if floor_name and floor_name in self._by_name:
            return self._by_name[floor_name]
        if self.floor_model is not None and wifi_scans is not None:
            votes: dict[str, int] = {}
            for scan in wifi_scans:
                if scan is None:
                    continue
                f = self.floor_model.floor_of(scan)
                if f is not None:
                    votes[f] = votes.get(f, 0) + 1
            if votes:
                best = max(votes, key=votes.get)
                # the model's floors are the floor names the survey recorded (or ids)
                found = self._by_name.get(best) or self.bundles.get(best)
                if found is not None:
                    return found
                raise LocalizationError(f"{where}: the floor model says floor {best}, which "
                                        "has no bundle")
        if len(self.bundles) == 1:
            return next(iter(self.bundles.values()))
        raise LocalizationError(f"{where}: the walk names no floor and no floor model decided; "
                                f"floors: {sorted(self._by_name)}")
