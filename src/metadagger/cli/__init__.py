"""The command line, the top layer: the ``metadagger`` process (:mod:`.entry`), its commands
(:mod:`.main`), its demo (:mod:`.demo`) and its benchmarks (:mod:`.bench`). ``python -m
metadagger.cli`` runs the same command line."""
