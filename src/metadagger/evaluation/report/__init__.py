"""A run's report, ``report/report.md``: one module per section, built from the run's artifacts alone.

:mod:`.build` puts the sections together; :mod:`.tables` holds what every section shares.
"""
