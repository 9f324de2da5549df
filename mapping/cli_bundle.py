"""``indoormap bundle info|verify|diff|list|publish|use``: a bundle's summary, checks and
differences, and a registry's versions. Reads bundles only, so it starts without the survey
and build modules (pandas, scipy)."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path

import click
import numpy as np

from localize.bundle import MapBundle, bundle_dirs, is_registry_floor_dir, load_bundle
from survey.errors import IndoormapError, RegistryError, RollbackRefused, WithdrawnVersion, \
    at_path
from survey.field_features import circular_mean_deg, wrap_deg

from .bundle_report import bundle_differences, metric_lines, plan_text
from .registry import Registry


@click.group("bundle")
def bundle_group() -> None:
    """Inspect, verify and compare map bundles; publish them into a registry, list it and
    switch its current versions."""


@bundle_group.command("info")
@click.argument("path", type=click.Path(exists=True, path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print the whole manifest.")
def bundle_info(path: Path, as_json: bool) -> None:
    """Summary of a bundle (verified first). A folder of bundles (what `build -o` writes, a
    registry's site folder) gives each bundle's, and with --json an object of their manifests
    keyed by folder name (exit 1 when any fails to load, after the others' summaries)."""
    paths = _bundle_paths((path,))
    one = len(paths) == 1 and paths[0] == path
    if as_json:  # several: {"F1": manifest, ...}, by path below PATH
        click.echo(json.dumps(load_bundle(path).manifest if one else {
            str(p.relative_to(path)): load_bundle(p).manifest for p in paths},
            indent=1, sort_keys=True))
        return
    if one:
        _say_bundle(load_bundle(path))
        return
    for p, b in _load_each(paths):  # each as it loads
        click.echo(f"{p}:")
        _say_bundle(b)


def _load_each(paths: list[Path]) -> Iterator[tuple[Path, MapBundle]]:
    """Each bundle of ``paths`` loaded (and verified) in turn; one that fails is said
    (``FAILED  path: why``) and the others go on; exit 1 at the end if any failed."""
    failed = 0
    for p in paths:
        try:
            b = load_bundle(p)
        except IndoormapError as err:
            failed += 1
            click.echo(f"FAILED  {at_path(p, str(err))}")
            continue
        yield p, b
    if failed:
        sys.exit(1)


def _say_bundle(b: MapBundle) -> None:
    """``bundle info``'s summary of one bundle."""
    m = b.manifest
    where = ("site-level bundle" if m.get("kind") == "site"
             else f"floor {m.get('floor_name') or m.get('floor_id', '?')}")
    click.echo(f"bundle {m['bundle_id']}\n  site {m['site_id']} {where} "
               f"(schema {m['schema_version']}, indoormap {m['software_version']})")
    if b.grid is not None:
        g = b.grid
        click.echo(f"  grid {g.width} x {g.height} cells of {g.cell_m} m, reachable "
                   f"{int(b.mask.sum())} cells")
        for name, meta in m["layers"].items():
            v = b.layers[name]
            finite = v[np.isfinite(v)].astype(np.float64)
            click.echo(f"  layer {name:<15} {meta['unit']:<4} {meta['kind']:<6} "
                       f"{100 * finite.size / max(int(b.mask.sum()), 1):5.1f} % of reachable "
                       f"cells, {_value_range(finite, meta['kind'] == 'angle')}"
                       if finite.size else f"  layer {name}: empty")
    width = max([15, *map(len, m.get("tables", {}))])  # ble_floor_intercept is 19 wide
    for name, meta in m.get("tables", {}).items():
        click.echo(f"  table {name:<{width}} {meta['rows']} rows")
    for line in metric_lines(m).values():
        click.echo(f"  {line}")
    click.echo(f"  built {m['build'].get('build_time')} from "
               f"{len(m['build'].get('source_walks', []))} walks"
               + ("" if m.get("kind") == "site" else f" on floor plan {plan_text(m)}"))


def _value_range(values: np.ndarray, angle: bool) -> str:
    """``range LO .. HI`` of a layer's values (n,); for angles (deg), which wrap at 360, the
    circular mean and the deviations from it (a heading offset of -12 to +9 deg read as the
    range 0.0 .. 360.0)."""
    if not angle:
        return f"range {values.min():.1f} .. {values.max():.1f}"
    mean = float(circular_mean_deg(values))
    dev = wrap_deg(values - mean)
    return f"circular mean {wrap_deg(mean):.1f}, {dev.min():+.1f} .. {dev.max():+.1f} around it"


def _bundle_paths(paths: tuple[Path, ...]) -> list[Path]:
    """Each path as the bundles it names: itself, the bundles in it (a build's output, a
    registry's site folder) or, for a registry's root, every site's floors; a path holding
    none stays as given, for load_bundle to say why it is no bundle."""
    out = []
    for p in paths:
        registry_root = p.is_dir() and any(p.glob("*/*/history.json"))
        found = bundle_dirs(p) or ([q for site in sorted(p.iterdir()) if site.is_dir()
                                    for q in bundle_dirs(site)] if registry_root else [])
        out += found or [p]
        if found != [p]:  # registry floors with none current are no bundle, but are said
            for floor in sorted(p.glob("*/*" if registry_root else "*")):
                if is_registry_floor_dir(floor) and not (floor / "CURRENT").exists():
                    click.echo(f"note: {floor}: no current version (indoormap bundle use "
                               "makes one current)", err=True)
    return out


@bundle_group.command("verify")
@click.argument("paths", nargs=-1, required=True, type=click.Path(path_type=Path))
def bundle_verify(paths: tuple[Path, ...]) -> None:
    """Verify bundles (every member's checksum, schema, no unlisted files). A folder of
    bundles (what `build -o` writes, a registry's site folder) is verified bundle by bundle; a
    registry's floor folder by its current version. Exit 1 if any fails."""
    for p, b in _load_each(_bundle_paths(paths)):
        click.echo(f"ok      {p} ({b.bundle_id[:16]})")


@bundle_group.command("diff")
@click.argument("a", type=click.Path(exists=True, path_type=Path))
@click.argument("b", type=click.Path(exists=True, path_type=Path))
def bundle_diff(a: Path, b: Path) -> None:
    """Differences between two bundles: build settings, walks, members, grid, layers."""
    ba, bb = load_bundle(a), load_bundle(b)
    if ba.bundle_id == bb.bundle_id:
        click.echo("identical")
        return
    for tag, m in (("a", ba.manifest), ("b", bb.manifest)):
        what = "site bundle" if m.get("kind") == "site" else f"floor {m.get('floor_name', '?')}"
        click.echo(f"{tag}: {m['bundle_id'][:16]} site {m['site_id'][:12]} {what}, built "
                   f"{m['build'].get('build_time')}")
    for line in bundle_differences(ba, bb):
        click.echo(line, err=line.startswith("warning:"))


@bundle_group.command("list")
@click.argument("registry", type=click.Path(exists=True, file_okay=False, path_type=Path))
def bundle_list(registry: Path) -> None:
    """Versions in a registry; * marks the current one. A floor whose history or pointer is
    damaged is named with the reason (its versions still listed when known) and the exit code
    is 1; the other floors list as usual."""
    entries = Registry(registry).list()
    if not entries:
        raise click.UsageError(f"{registry}: not a registry, or nothing published in it (a "
                               "registry holds <site>/<floor>/history.json; build with "
                               "--registry or use `indoormap bundle publish`)")
    problems = {}
    for e in entries:
        if e["problem"]:
            problems.setdefault(f"{e['site']}/{e['floor']}", e["problem"])
        if e["bundle_id"] is not None:
            click.echo(f"{'*' if e['current'] else ' '} {e['site']}/{e['floor']} #{e['seq']} "
                       f"{e['bundle_id']}")
    for floor, problem in problems.items():
        click.echo(f"error: {floor}: {problem}", err=True)
    if problems:
        sys.exit(1)


@bundle_group.command("publish")
@click.argument("paths", nargs=-1, required=True,
                type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--registry", "registry_dir", required=True, type=click.Path(path_type=Path),
              help="Registry folder (created if missing).")
@click.option("--no-current", is_flag=True,
              help="Only add the versions; keep the current pointers where they are.")
def bundle_publish(paths: tuple[Path, ...], registry_dir: Path, no_current: bool) -> None:
    """Copy verified bundles into a registry as new versions and make them current. PATHS are
    bundles or folders of bundles (what `build -o` writes)."""
    reg = Registry(registry_dir)
    for p in _bundle_paths(paths):
        try:
            e = reg.publish(p, make_current=not no_current)
        except RollbackRefused as err:  # an older or a withdrawn version published again
            raise RegistryError(already_published_text(p, registry_dir, err)) from err
        click.echo(f"{p}: {e['bundle_id'][:16]} #{e['seq']}"
                   + ("" if no_current else " (current)")
                   + ("; its damaged copy in the registry was replaced" if e.get("repaired")
                      else ""))


def already_published_text(path: Path, registry_dir: Path, err: RollbackRefused) -> str:
    """What publishing a bundle the registry holds as an older version than the current one,
    or as one a rollback withdrew, says: which version it is and the command that makes it
    current."""
    if isinstance(err, WithdrawnVersion):
        return (f"{path}: already published as #{err.seq}, which was rolled back from (the "
                f"current is #{err.current_seq}); to make it current again: indoormap bundle "
                f"use {registry_dir} {err.where} '#{err.seq}'")
    return (f"{path}: already published as #{err.seq}, older than {err.current_text}; to make "
            f"it current: indoormap bundle use {registry_dir} {err.where} '#{err.seq}' "
            "--rollback")


@bundle_group.command("use")
@click.argument("registry", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("site_floor", metavar="SITE/FLOOR")
@click.argument("version", metavar="VERSION")
@click.option("--rollback", is_flag=True,
              help="Allow pointing at an older version than the current one.")
def bundle_use(registry: Path, site_floor: str, version: str, rollback: bool) -> None:
    """Make a published VERSION (bundle id, a unique prefix of it, or #SEQ; a bare SEQ
    that begins no other version's id) of SITE/FLOOR current. Moving to an older version
    needs --rollback."""
    site, sep, floor = site_floor.partition("/")
    if not sep:
        raise click.BadParameter(f"expected SITE/FLOOR, got {site_floor!r}",
                                 param_hint="SITE/FLOOR")
    reg = Registry(registry)
    history = reg.writable_history(site, floor)
    if not history:
        raise click.BadParameter(f"{registry}: nothing published for {site_floor}",
                                 param_hint="SITE/FLOOR")
    if version.startswith("#"):
        match = [h for h in history if str(h["seq"]) == version[1:]]
    else:
        match = [h for h in history if h["bundle_id"].startswith(version)]
        seq = [h for h in history if str(h["seq"]) == version]  # `bundle list` prints #SEQ
        if seq and match and seq != match:
            raise click.BadParameter(
                f"{version!r} is #{version} and begins bundle id "
                f"{match[0]['bundle_id'][:12]}; say '#{version}' or more of the id",
                param_hint="VERSION")
        match = match or seq
    if len(match) != 1:
        known = ", ".join(f"#{h['seq']} {h['bundle_id'][:12]}" for h in history)
        raise click.BadParameter(f"{version!r} names {len(match)} versions of {site_floor}; "
                                 f"published: {known}", param_hint="VERSION")
    try:
        reg.set_current(site, floor, match[0]["bundle_id"], allow_rollback=rollback)
    except RollbackRefused as err:
        raise RegistryError(f"{site_floor}: #{err.seq} is older than {err.current_text}; pass "
                            "--rollback to go back to it") from err
    click.echo(f"{site_floor}: current is #{match[0]['seq']} {match[0]['bundle_id'][:16]}")
