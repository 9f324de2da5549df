"""The ``indoormap`` command table: each command is imported only when used, so that
``indoormap --help`` and the commands that read bundles only start without pandas and scipy."""

from __future__ import annotations

import subprocess
import sys

import click
from click.testing import CliRunner

from survey.cli import COMMANDS, main

HEAVY = ("pandas", "scipy", "sklearn", "matplotlib", "numba", "shapely")


def _heavy_modules_after(args: list[str]) -> list[str]:
    """The heavy libraries imported by running ``indoormap ARGS`` in a fresh interpreter."""
    code = ("import sys\nfrom survey.cli import main\n"
            f"try:\n    main({args!r})\nexcept SystemExit:\n    pass\n"
            f"heavy = {{m.split('.')[0] for m in sys.modules}} & {set(HEAVY)!r}\n"
            "print(','.join(sorted(heavy)), file=sys.stderr)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return [m for m in out.stderr.strip().split(",") if m]


def test_every_listed_command_resolves_to_itself():
    ctx = click.Context(main)
    for name, (_, _, short_help) in COMMANDS.items():
        command = main.get_command(ctx, name)
        assert isinstance(command, click.Command) and command.name == name
        assert len(short_help) <= 72 and short_help.endswith(".")  # one unbroken line
    assert main.get_command(ctx, "no-such") is None


def test_top_level_help_lists_every_command_without_loading_them():
    out = CliRunner().invoke(main, ["--help"])
    assert out.exit_code == 0
    listing = out.output.split("Commands:")[1]
    for name, (_, _, short_help) in COMMANDS.items():
        assert f"{name} " in listing and short_help in " ".join(listing.split())
    assert _heavy_modules_after(["--help"]) == []


def test_bundle_commands_and_localize_help_start_light():
    """The bundle commands read bundles only; localize's runtime is numpy and pyarrow."""
    assert _heavy_modules_after(["bundle", "--help"]) == []
    assert _heavy_modules_after(["localize", "--help"]) == []
    assert "pandas" in _heavy_modules_after(["build", "--help"])  # the check can fail


def test_unknown_command_is_a_usage_error():
    out = CliRunner().invoke(main, ["nosuch"])
    assert out.exit_code == 2 and "No such command 'nosuch'" in out.output
    out = CliRunner().invoke(main, ["bulid"])  # click's suggestion, from the table
    assert out.exit_code == 2 and "Did you mean 'build'?" in out.output
