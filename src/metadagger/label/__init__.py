"""A person as the expert: a gate's DAgger rounds on one seed of a run, labelled at a local web page.

``metadagger label`` (docs/label.md) runs :func:`~metadagger.label.session.run_label`: the
session's loop (:mod:`~metadagger.label.session`), the labels kept as they arrive
(:mod:`~metadagger.label.store`), what the page and the loop share (:mod:`~metadagger.label.desk`),
how a person labels a task (:mod:`~metadagger.label.forms`), what a person sees of a state beyond
its frame (:mod:`~metadagger.label.overview`) and the page's server (:mod:`~metadagger.label.server`,
serving ``page.html`` and ``page.js``).
"""
