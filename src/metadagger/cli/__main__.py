"""``python -m metadagger.cli``: the ``metadagger`` command line."""

from metadagger.cli.main import main

main()
