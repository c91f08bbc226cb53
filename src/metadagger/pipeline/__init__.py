"""Stages over one run folder, above evaluation: the run's config (:mod:`.run_config`, built from
the packaged YAML presets in ``presets/``) and the stages and ``reproduce`` (:mod:`.stages`)."""
