"""``python -m metadagger.cli``: the ``metadagger`` command line."""

from metadagger.cli.entry import run

run()
