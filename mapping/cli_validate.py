"""``indoormap validate``: is a floor's map good enough, and where must the surveyor walk again?"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from survey.errors import PublishError
from survey.publish import atomic_directory, check_parent_is_a_folder, refuse_to_replace


@click.command("validate")
@click.argument("bundle", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--store", "store_dir", type=click.Path(exists=True, file_okay=False,
                                                      path_type=Path), default=None,
              help="The processed survey store the bundle was built from (needed for held-out "
                   "accuracy, consistency and data quality).")
@click.option("-o", "--out", "out_dir", required=True, type=click.Path(file_okay=False,
                                                                        path_type=Path),
              help="Report folder: report.html, metrics.json, figures/*.png.")
@click.option("--thresholds", "thresholds_file", type=click.Path(exists=True, dir_okay=False,
                                                                 path_type=Path), default=None,
              help="JSON object overriding default thresholds (null disables a check); see "
                   "docs/validation.md.")
@click.option("--floor-dir", type=click.Path(exists=True, file_okay=False, path_type=Path),
              default=None, help="Floor folder with floor_image.png / floor_info.json for the "
                                 "figures (default: found from the store's source paths).")
@click.option("--holdout-subsample", type=click.IntRange(min=1), default=5, show_default=True,
              help="Leave-one-walk-out uses every n-th sample.")
@click.option("--holdout-folds", type=click.IntRange(min=1), default=10, show_default=True,
              help="Levelling is refitted in this many folds of walks during leave-one-walk-out.")
@click.option("--no-baseline", is_flag=True,
              help="Leave the slow linear baseline pipeline out of the held-out comparison "
                   "(figures then differ from benchmarks/map_accuracy.py).")
@click.option("--no-holdout", is_flag=True, help="Skip the held-out evaluation.")
@click.option("-q", "--quiet", is_flag=True, help="No progress messages.")
@click.option("--overwrite", is_flag=True, help="Replace an existing report folder.")
def validate_command(bundle: Path, store_dir: Path | None, out_dir: Path,
                     thresholds_file: Path | None, floor_dir: Path | None,
                     holdout_subsample: int, holdout_folds: int, no_baseline: bool,
                     no_holdout: bool, quiet: bool, overwrite: bool) -> None:
    """Validate a floor's map BUNDLE: coverage, consistency, held-out accuracy, predicted
    localization quality, calibration, data quality. Writes REPORT_DIR/report.html (one
    self-contained file), metrics.json and figures/*.png.

    Exit status: 0 when every threshold holds, 1 when any fails (or the inputs are unusable),
    2 on usage errors."""
    from localize.cli_common import refuse_output_inside_data
    from mapping.validate import (
        ValidateParams,
        ValidationError,
        load_thresholds,
        summary_lines,
        validate_bundle,
        write_metrics,
    )

    refuse_output_inside_data(out_dir)  # files there made a bundle fail its checks
    check_parent_is_a_folder(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()):  # said before minutes of work
        refuse_to_replace(out_dir, overwrite)
        if not (out_dir / "metrics.json").is_file():
            raise PublishError(f"{out_dir} exists and is not a validation report; --overwrite "
                               "replaces reports only, move it away first")
    try:
        thresholds = load_thresholds(thresholds_file)
    except ValidationError as err:
        raise click.BadParameter(str(err), param_hint="--thresholds") from err
    params = ValidateParams(holdout=not no_holdout, holdout_subsample=holdout_subsample,
                            holdout_levelling_folds=holdout_folds,
                            holdout_baseline=not no_baseline)
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if not quiet:
            click.echo(f"[{time.perf_counter() - t0:5.1f} s] {msg}", err=True)

    result = validate_bundle(bundle, store_dir, thresholds=thresholds, params=params,
                             floor_dir=floor_dir, progress=say)
    say("figures and report")
    with atomic_directory(out_dir, overwrite=True) as tmp:  # the whole report, or the old one
        try:
            from mapping.report_html import write_report
        except ImportError as err:  # matplotlib missing: the verdict and metrics still stand
            report = out_dir / write_metrics(result, tmp).name
            click.echo(f"warning: no HTML report or figures ({err}); wrote {report}",
                       err=True)
        else:
            report = out_dir / write_report(result, tmp).name
    for line in summary_lines(result):
        click.echo(line)
    click.echo(f"report: {report} ({time.perf_counter() - t0:.0f} s)")
    sys.exit(0 if result.verdict == "pass" else 1)
