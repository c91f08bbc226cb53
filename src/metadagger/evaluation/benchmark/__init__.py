"""The query benchmark: every method on one success-against-queries axis, from the same start.

- :mod:`.config`: the ``benchmark`` section (methods, seeds, gate grids);
- :mod:`.methods`: every method declared once, a typed key per row; :mod:`.labels`: their names;
- :mod:`.protocol`: which rows are missing, their stamps, the run over seeds and what it writes;
- :mod:`.seed_chains`: one seed's chains of rollouts, from w_BC to every method's rows;
- :mod:`.ledger`: the query ledger (which states each round labelled, takeovers, episodes asked);
- :mod:`.coverage`: the coverage gap of a seed's DAgger states;
- :mod:`.summary`: the rows summarised, paired and read at equal budgets;
- :mod:`.figure`, :mod:`.coverage_figure`: the two figures.
"""
