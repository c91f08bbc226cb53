"""Imitation learning on a task's envs: rollouts (one at a time or in lockstep lanes), datasets,
behavioural cloning, query rules (gates), the cosine early stop and metrics.

Two DAggers live in the package: :mod:`~metadagger.imitation.whole_policy_dagger`, the whole
network over many seeds (pi*'s and ``metadagger demo``'s), and MetaL DAgger's own, one seed with
a frozen trunk and a head refitted each round, :func:`metadagger.metal_dagger.method.dagger_rounds`.
"""
