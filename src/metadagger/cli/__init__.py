"""The command line, the top layer: ``metadagger`` (:mod:`.main`), its demo (:mod:`.demo`) and
its benchmarks (:mod:`.bench`). ``python -m metadagger.cli`` runs the same command line."""
