"""The results registry, the layer above the pipeline: the small artifacts of the canonical runs
under ``results/<run>/`` (:mod:`.registry`), and the tables and figures of README.md and docs/
written from them between marked blocks (:mod:`.blocks`, whose kinds :mod:`.tables` renders)."""
