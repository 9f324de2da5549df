"""The ``indoormap`` command line: a thin layer over the Python API.

Exit codes: 0 success, 1 data or validation failure, 2 usage error (click's own).
"""

from __future__ import annotations

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


class _Group(click.Group):
    """Maps indoormap's own errors and the operating system's (a read-only or full disk, no
    permission) to a one-line message and exit code 1; a SIGTERM unwinds like Ctrl-C does."""

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


def _register() -> None:
    from .cli_ingest import ingest_command
    from .cli_process import process_command, survey_report_command
    from .cli_store import store_group
    from .sim.cli import simulate

    from mapping.cli_build import build_command, bundle_group
    from localize.cli import evaluate_command, localize_command
    from localize.cli_radio import floor_command, wifi_locate_command
    from mapping.cli_validate import validate_command

    for command in (simulate, ingest_command, store_group, process_command,
                    survey_report_command, build_command, bundle_group, validate_command, localize_command,
                    evaluate_command, floor_command, wifi_locate_command):
        main.add_command(command)


_register()


if __name__ == "__main__":  # python -m survey.cli
    main()
