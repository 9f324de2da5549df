"""``python -m survey``: the ``indoormap`` command line, from a checkout not installed."""

from survey.entry import run

run()
