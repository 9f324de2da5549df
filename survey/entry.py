"""The ``indoormap`` console script: imports the command-line interface under the handling its
commands give Ctrl-C ("Aborted!" and exit status 1, not a traceback from the middle of an
import). Each command's own module is imported when it runs, under click's handling."""

from __future__ import annotations

import sys


def run() -> None:
    """Entry point of ``indoormap`` (``[project.scripts]`` in ``pyproject.toml``)."""
    try:
        from .cli import main
    except KeyboardInterrupt:
        print("Aborted!", file=sys.stderr)  # what click says for a Ctrl-C within a command
        sys.exit(1)
    main()


if __name__ == "__main__":  # python -m survey.entry (it ran nothing and exited 0)
    run()
