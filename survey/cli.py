"""The ``indoormap`` command line: a thin layer over the Python API.

Exit codes: 0 success, 1 data or validation failure, 2 usage error (click's own).
"""

from __future__ import annotations

import difflib
import importlib
import os
import signal
import sys
import threading

import click

from . import __version__
from .errors import IndoormapError


def _terminated(signum: int, frame) -> None:
    """SIGTERM as an exception, so that temporary files and folders are removed on the way out
    (a killed build leaves no store in the temporary folder and no half bundle)."""
    raise SystemExit(128 + signum)


# name: (module, attribute, the line `indoormap --help` gives it). A command's module is
# imported only when that command runs (or its own --help is asked for): the survey and
# mapping modules load pandas and scipy, about a second, which `indoormap localize`, whose
# runtime needs numpy and pyarrow only, and `indoormap --help` need not wait for.
COMMANDS: dict[str, tuple[str, str, str]] = {
    "build": ("mapping.cli_build", "build_command",
              "Build map bundles of a floor or a whole site from its survey."),
    "bundle": ("mapping.cli_bundle", "bundle_group",
               "Inspect, verify, compare and publish map bundles."),
    "evaluate": ("localize.cli", "evaluate_command",
                 "Error of localizers at the waypoints of walks, with CDFs."),
    "floor": ("localize.cli_radio", "floor_command",
              "Predicted floor per scan and per walk from radio scans."),
    "ingest": ("survey.cli_ingest", "ingest_command",
               "Ingest survey traces into a survey store."),
    "localize": ("localize.cli", "localize_command",
                 "Localize walks on map bundles: positions per step and a plot."),
    "process": ("survey.cli_process", "process_command",
                "Position and calibrate a store's samples along their walks."),
    "simulate": ("survey.sim.cli", "simulate",
                 "Simulate a surveyed site (traces, plans and truth)."),
    "store": ("survey.cli_store", "store_group",
              "Inspect and verify survey stores."),
    "survey-report": ("survey.cli_process", "survey_report_command",
                      "Per-walk quality of a survey, a row per walk (or leg)."),
    "validate": ("mapping.cli_validate", "validate_command",
                 "Validate a floor's map bundle: coverage, consistency, held-out error."),
    "wifi-locate": ("localize.cli_radio", "wifi_locate_command",
                    "Wi-Fi (or BLE) position per scan from a bundle's fingerprints."),
}


class _Group(click.Group):
    """Maps indoormap's own errors and the operating system's (a read-only or full disk, no
    permission) to a one-line message and exit code 1; a SIGTERM unwinds like Ctrl-C does.
    Its commands (:data:`COMMANDS`) are imported when they are used."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS:
            return None
        module, attribute, short_help = COMMANDS[name]
        command = getattr(importlib.import_module(module), attribute)
        command.short_help = short_help
        return command

    def resolve_command(self, ctx: click.Context, args: list[str]):
        name = args[0] if args else ""
        if name not in COMMANDS and not name.startswith("-") and not ctx.resilient_parsing:
            # click's own "Did you mean" reads self.commands, which the table leaves empty
            close = difflib.get_close_matches(name, list(COMMANDS), n=1)
            raise click.UsageError(f"No such command {name!r}."
                                   + (f" Did you mean {close[0]!r}?" if close else ""), ctx)
        return super().resolve_command(ctx, args)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The command list from :data:`COMMANDS`, without importing the commands."""
        with formatter.section("Commands"):
            formatter.write_dl([(name, COMMANDS[name][2]) for name in self.list_commands(ctx)])

    def invoke(self, ctx: click.Context):
        # only where SIGTERM would kill us anyway: an embedding program's handler (or its
        # choice to ignore the signal) is left alone
        ours = (threading.current_thread() is threading.main_thread()
                and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL)
        if ours:
            signal.signal(signal.SIGTERM, _terminated)
        try:
            return super().invoke(ctx)
        except IndoormapError as err:
            click.echo(f"error: {err}", err=True)
            sys.exit(1)
        except BrokenPipeError:  # `indoormap ... | head`: the reader has gone, say nothing
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())  # nor at the interpreter's final flush
            sys.exit(1)
        except OSError as err:  # the machine's refusal: read-only, permissions, disk full
            where = f"{err.filename}: " if err.filename else ""
            click.echo(f"error: {where}{err.strerror or err}", err=True)
            sys.exit(1)
        finally:
            if ours:
                signal.signal(signal.SIGTERM, signal.SIG_DFL)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="indoormap")
def main() -> None:
    """indoormap: survey data to versioned map bundles for smartphone indoor positioning."""


if __name__ == "__main__":  # python -m survey.cli
    main()
