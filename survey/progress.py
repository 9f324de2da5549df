"""Progress of long CLI work on standard error: a bar on a terminal, lines in a log.

``click.progressbar`` draws nothing but its label when the stream is not a terminal (a CI log,
``2> file``), so a long ingest there looked stuck. :func:`progress` shows the bar on a
terminal and otherwise prints ``label: done/total`` at about every tenth of the work and at
the end.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator
from typing import TextIO

import click


@contextlib.contextmanager
def progress(label: str, total: int = 1, *, unit: str = "",
             file: TextIO | None = None) -> Iterator[Callable[[int, int], None]]:
    """Yields ``update(done, total)``: ``done`` of ``total`` items finished (totals may grow).

    ``unit`` names the items in the log lines ("files", "walks")."""
    out = file if file is not None else sys.stderr
    if out.isatty():
        with click.progressbar(length=max(total, 1), label=label, file=out,
                               show_pos=True) as bar:
            def update_bar(done: int, n: int) -> None:
                bar.length = max(n, 1)
                bar.update(done - bar.pos)

            yield update_bar
        return
    shown = 0  # the last count printed

    def update_log(done: int, n: int) -> None:
        nonlocal shown
        step = max(n // 10, 1)
        if (done >= n or done // step > shown // step) and done != shown:
            click.echo(f"{label}: {done}/{n}" + (f" {unit}" if unit else ""), file=out)
            shown = done

    yield update_log
