"""``python -m metadagger.cli``: the ``metadagger`` command line."""

from metadagger.cli import run

run()
