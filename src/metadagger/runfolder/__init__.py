"""The machinery of one run folder: its paths (:mod:`.layout`), what each artifact was made from
(:mod:`.stamps`) and the per-seed driver that plans, runs, saves and logs a stage's work
(:mod:`.driver`). Used by metal_dagger, mapping and evaluation; imports only :mod:`metadagger.utils`,
:mod:`metadagger.errors` and :mod:`metadagger.version`.
"""
