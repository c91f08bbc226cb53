"""Query rules of gated DAgger on synthetic features: labelled states in one cluster, queries near and far."""

from __future__ import annotations

import pytest
import torch

from metadagger.errors import UserError
from metadagger.imitation.gate_registry import gate_declarations, gated_names, make_gate
from metadagger.imitation.gate_view import Episode, GateMemory, Labelled, LearnerView
from metadagger.imitation.gates import EnsembleGate, NoveltyGate, RandomGate, SafeGate, above_quantile
from metadagger.imitation.memory_gates import ConformalGate, ThriftyGate, conformal_threshold
from metadagger.utils.kernels import mkl_vector_math_calls

F = 32
N_NEAR = N_FAR = 100


def gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _heads(features: int, outputs: int, seed: int) -> torch.Tensor:
    return torch.randn(outputs * (features + 1), generator=gen(seed))


def view(
    features: torch.Tensor,
    learner: torch.Tensor,
    labelled: Labelled,
    generator: torch.Generator,
    *,
    memory: GateMemory | None = None,
    head: torch.Tensor | None = None,
    **reads: torch.Tensor,
) -> LearnerView:
    """The round's view with the learner's actions as given, acting with ``head`` (a random one of
    three classes or of the actions' length, where not given)."""
    outputs = 3 if labelled.discrete else labelled.labels.shape[1]
    head = _heads(features.shape[1], outputs, 9) if head is None else head
    return LearnerView.of(features, head, labelled, actions=learner, generator=generator, memory=memory, **reads)


def actions(labels: torch.Tensor, discrete: bool) -> torch.Tensor:
    """Class indices as they are, or as 2-d continuous actions (one point per class)."""
    return labels if discrete else torch.stack([labels.float(), -labels.float()], dim=1)


def scene(discrete: bool) -> tuple[torch.Tensor, torch.Tensor, Labelled]:
    """Labelled states in three tight blobs (one class each); queries: N_NEAR in the blobs, then N_FAR far away."""
    g = gen(1)
    centres = torch.randn(3, F, generator=g)
    classes = torch.arange(60) % 3
    labels = actions(classes, discrete)
    labelled = Labelled(centres[classes] + 0.1 * torch.randn(60, F, generator=g), labels, labels.clone())
    near_classes = torch.arange(N_NEAR) % 3
    near = centres[near_classes] + 0.1 * torch.randn(N_NEAR, F, generator=g)
    far = 4 * torch.randn(N_FAR, F, generator=g)
    learner = actions(torch.cat([near_classes, torch.zeros(N_FAR, dtype=torch.int64)]), discrete)
    return torch.cat([near, far]), learner, labelled


def mismatch_scene(discrete: bool) -> tuple[torch.Tensor, torch.Tensor, Labelled]:
    """Labelled states in two blobs: in blob A the learner agrees with the expert, in blob B it does not.
    Queries: N_NEAR states in blob A, then N_FAR in blob B."""
    g = gen(2)
    a, b = torch.randn(2, F, generator=g)
    feats = torch.cat([a + 0.3 * torch.randn(40, F, generator=g), b + 0.3 * torch.randn(20, F, generator=g)])
    classes = torch.randint(3, (60,), generator=g)
    learner_classes = torch.cat([classes[:40], (classes[40:] + 1) % 3])
    labelled = Labelled(feats, actions(classes, discrete), actions(learner_classes, discrete))
    if not discrete:  # small learner errors in blob A, so the continuous rule is not just "distance > 0"
        labelled = Labelled(feats, labelled.labels, labelled.learner_actions + 0.05 * torch.randn(60, 2, generator=g))
    queries = torch.cat([a + 0.3 * torch.randn(N_NEAR, F, generator=g), b + 0.3 * torch.randn(N_FAR, F, generator=g)])
    return queries, actions(torch.zeros(len(queries), dtype=torch.int64), discrete), labelled


both = pytest.mark.parametrize("discrete", [True, False], ids=["discrete", "box"])
every_gate = pytest.mark.parametrize("name", gated_names())  # the oracle reads expert labels: tested apart


@both
@every_gate
def test_each_gate_returns_a_bool_mask_per_state(name, discrete):
    features, learner, labelled = mismatch_scene(discrete)
    if gate_declarations()[name].gate.needs_classes and not discrete:
        with pytest.raises(UserError, match="reads the learner's class distribution, but it acts with action vectors"):
            make_gate(name, 0.5).choose(view(features, learner, labelled, gen()))
        return
    mask = make_gate(name, 0.5).choose(view(features, learner, labelled, gen())).mask
    assert mask.dtype == torch.bool and mask.shape == (len(features),)
    assert 0 < int(mask.sum()) < len(features)


@both
@every_gate
def test_gates_are_deterministic_given_the_generator_seed(name, discrete):
    if gate_declarations()[name].gate.needs_classes and not discrete:
        return  # refused on action vectors: test_each_gate_returns_a_bool_mask_per_state
    features, learner, labelled = mismatch_scene(discrete)
    gate = make_gate(name, 0.3)
    first = gate.choose(view(features, learner, labelled, gen(7))).mask
    assert torch.equal(first, gate.choose(view(features, learner, labelled, gen(7))).mask)


def test_ensemble_heads_are_drawn_from_the_generator():
    features, learner, labelled = scene(False)
    gate = EnsembleGate(quantile=0.5)
    assert not torch.equal(*(gate.scores(view(features, learner, labelled, gen(s))) for s in (1, 2)))


def test_random_gate_labels_about_p_of_the_states():
    features, learner, labelled = scene(True)
    features, learner = features.repeat(10, 1), learner.repeat(10)  # 2000 states
    for p in (0.1, 0.5, 0.8):
        share = RandomGate(p=p).choose(view(features, learner, labelled, gen(3))).mask.float().mean().item()
        assert abs(share - p) < 4 * (p * (1 - p) / len(features)) ** 0.5
    assert not RandomGate(p=0.0).choose(view(features, learner, labelled, gen())).mask.any()
    assert RandomGate(p=1.0).choose(view(features, learner, labelled, gen())).mask.all()
    masks = [RandomGate(p=0.5).choose(view(features, learner, labelled, gen(s))).mask for s in (1, 2)]
    assert not torch.equal(*masks)


def test_quantile_rule_labels_the_top_share_of_distinct_scores():
    scores = torch.randperm(2000, generator=gen()).float()
    for q in (0.0, 0.25, 0.5, 0.9):
        mask = above_quantile(scores, q)
        assert abs(int(mask.sum()) - (1 - q) * 2000) <= 1
        assert scores[mask].min() > scores[~mask].max()
    # ties at the threshold are left out: all-equal scores label nothing
    assert not above_quantile(torch.ones(50), 0.5).any()
    assert torch.equal(
        above_quantile(torch.tensor([0.0, 1.0, 1.0, 1.0, 2.0]), 0.5), torch.tensor([False, False, False, False, True])
    )


@both
@pytest.mark.parametrize(
    "gate",
    [EnsembleGate(quantile=0.5), NoveltyGate(quantile=0.5), NoveltyGate(quantile=0.5, k=3)],
    ids=["ensemble", "novelty", "novelty-k3"],
)
def test_uncertainty_gates_select_the_states_far_from_the_labelled_data(gate, discrete):
    features, learner, labelled = scene(discrete)
    for seed in range(3):
        mask = gate.choose(view(features, learner, labelled, gen(seed))).mask
        assert mask[N_NEAR:].all() and not mask[:N_NEAR].any()


@both
def test_ensemble_disagrees_more_off_the_labelled_data(discrete):
    features, learner, labelled = scene(discrete)
    scores = EnsembleGate(quantile=0.5, K=8).scores(view(features, learner, labelled, gen()))
    assert scores[N_NEAR:].min() > scores[:N_NEAR].max()


@both
def test_safe_gate_selects_states_like_the_labelled_mismatches(discrete):
    features, learner, labelled = mismatch_scene(discrete)
    mask = SafeGate(quantile=0.5).choose(view(features, learner, labelled, gen())).mask
    assert mask[N_NEAR:].all() and not mask[:N_NEAR].any()


@both
def test_safe_gate_labels_everything_when_there_is_no_mismatch_to_learn_from(discrete):
    features, learner, labelled = scene(discrete)  # learner action == label on every labelled state
    assert SafeGate(quantile=0.9).choose(view(features, learner, labelled, gen())).mask.all()


@both
def test_thrifty_gate_without_outcomes_to_learn_from_labels_the_novel_states(discrete):
    features, learner, labelled = scene(discrete)
    memory = GateMemory(episodes=[Episode(labelled.features, succeeded=True)])  # the demonstration only: no risk
    mask = ThriftyGate(rate=0.5).choose(view(features, learner, labelled, gen(), memory=memory)).mask
    assert mask[N_NEAR:].all() and not mask[:N_NEAR].any()
    assert memory.notes["thrifty"]["risk"] == [] and len(memory.notes["thrifty"]["novelty"]) == 1


def test_thrifty_risk_is_higher_where_episodes_failed():
    g = gen(4)
    a, b = torch.randn(2, F, generator=g)
    near = lambda centre, n: centre + 0.3 * torch.randn(n, F, generator=g)  # noqa: E731
    episodes = [
        Episode(near(a, 50), succeeded=True),
        Episode(near(b, 50), succeeded=False),
        Episode(near(a, 30), succeeded=True),
    ]
    gate = ThriftyGate(rate=0.2)
    risk = gate.risk(torch.cat([near(a, 40), near(b, 40)]), episodes)
    assert risk[40:].min() > risk[:40].max()
    assert gate.risk(torch.cat([near(a, 5), near(b, 5)]), episodes[:1]) is None  # one outcome: nothing to learn


def test_thrifty_gate_labels_the_risky_states_beside_the_novel_ones():
    features, learner, labelled = mismatch_scene(False)  # queries: N_NEAR in blob A, then N_FAR in blob B
    a, b = features[:N_NEAR], features[N_NEAR:]
    memory = GateMemory(episodes=[Episode(a[::2], succeeded=True), Episode(b[::2], succeeded=False)])
    gate = ThriftyGate(rate=0.3)
    mask = gate.choose(view(features, learner, labelled, gen(), memory=memory)).mask
    novel = gate.choose(view(features, learner, labelled, gen(), memory=GateMemory())).mask  # novelty alone
    assert not (novel & ~mask).any()  # the union of both tests: every novel state, and
    risky = mask & ~novel
    assert risky.any() and not risky[:N_NEAR].any()  # risky ones only where the episodes failed
    assert int(mask[N_NEAR:].sum()) >= 0.3 * len(features)  # the riskiest 30% of the states are all in blob B


def test_thrifty_thresholds_hold_every_estimate_of_the_run():
    features, learner, labelled = scene(True)  # N_NEAR familiar states, then N_FAR novel ones
    gate, memory = ThriftyGate(rate=0.25), GateMemory()
    first = gate.choose(view(features, learner, labelled, gen(), memory=memory)).mask
    assert first[N_NEAR:].sum() == 50 and not first[:N_NEAR].any()  # the top quarter of 200 states
    # a round of familiar states only: the run's threshold sits among the novel states, so none is labelled,
    # where a threshold from this round alone would label a quarter of them
    again = gate.choose(view(features[:N_NEAR], learner[:N_NEAR], labelled, gen(), memory=memory)).mask
    assert not again.any() and len(memory.notes["thrifty"]["novelty"]) == 2
    assert ThriftyGate(rate=0.25).choose(view(features[:N_NEAR], learner[:N_NEAR], labelled, gen())).mask.sum() == 25


def test_conformal_threshold_is_the_finite_sample_quantile():
    scores = torch.arange(10.0)
    assert conformal_threshold(scores, 0.5) == 5.0  # the ceil(11 * 0.5) = 6th smallest
    assert conformal_threshold(scores, 0.1) == 9.0  # the 10th
    assert conformal_threshold(scores, 0.05) == float("inf")  # rank 11 of 10: nothing is ever labelled


@both
def test_conformal_gate_calibrates_once_on_the_first_round(discrete):
    features, learner, labelled = scene(discrete)
    near, far = features[:N_NEAR], features[N_NEAR:]
    gate, memory = ConformalGate(alpha=0.1), GateMemory()
    first = gate.choose(view(near, learner[:N_NEAR], labelled, gen(), memory=memory)).mask
    assert int(first.sum()) == N_NEAR - 91  # above the ceil(101 * 0.9) = 91st smallest of 100 distinct distances
    threshold = memory.notes["conformal"]
    assert gate.choose(view(far, learner[N_NEAR:], labelled, gen(), memory=memory)).mask.all()  # far beyond it
    assert memory.notes["conformal"] == threshold  # kept, not recalibrated on the far round
    assert int(ConformalGate(alpha=0.1).choose(view(far, learner[N_NEAR:], labelled, gen())).mask.sum()) == N_FAR - 91


def test_make_gate_maps_the_sweep_value_and_options():
    assert make_gate("random", 0.2) == RandomGate(p=0.2)
    assert make_gate("ensemble", 0.8) == EnsembleGate(quantile=0.8, K=5)
    assert make_gate("ensemble", 0.8, K=3).K == 3
    assert make_gate("novelty", 0.7, k=4) == NoveltyGate(quantile=0.7, k=4)
    assert make_gate("safe", 0.6) == SafeGate(quantile=0.6)
    assert make_gate("thrifty", 0.1, K=3) == ThriftyGate(rate=0.1, K=3)
    assert make_gate("conformal", 0.2, k=2) == ConformalGate(alpha=0.2, k=2)


def test_bad_names_settings_and_options_are_user_errors():
    with pytest.raises(
        UserError,
        match="unknown gate 'dropout': expected one of random, ensemble, safe, novelty, least-confidence, margin, "
        "entropy, thrifty, conformal, oracle",
    ):
        make_gate("dropout", 0.5)
    with pytest.raises(UserError, match=r"RandomGate.p must be in \[0, 1\], got 1.5"):
        make_gate("random", 1.5)
    for name in ("ensemble", "safe", "novelty"):
        with pytest.raises(UserError, match=r"quantile must be in \[0, 1\), got 1.0"):
            make_gate(name, 1.0)
        with pytest.raises(UserError, match=r"quantile must be in \[0, 1\), got -0.1"):
            make_gate(name, -0.1)
    with pytest.raises(UserError, match="EnsembleGate.K must be an integer >= 2, got 1"):
        make_gate("ensemble", 0.5, K=1)
    with pytest.raises(UserError, match="NoveltyGate.k must be an integer >= 1, got 0"):
        make_gate("novelty", 0.5, k=0)
    with pytest.raises(UserError, match="SafeGate.ridge must be > 0, got 0"):
        make_gate("safe", 0.5, ridge=0)
    with pytest.raises(UserError, match="unknown option.* k for gate 'ensemble': expected K, ridge"):
        make_gate("ensemble", 0.5, k=3)
    for value in (0.0, 1.0):
        with pytest.raises(UserError, match=rf"ThriftyGate.rate must be in \(0, 1\), got {value}"):
            make_gate("thrifty", value)
        with pytest.raises(UserError, match=rf"ConformalGate.alpha must be in \(0, 1\), got {value}"):
            make_gate("conformal", value)


def test_mismatched_inputs_are_user_errors():
    features, learner, labelled = scene(True)
    gate = NoveltyGate(quantile=0.5)
    with pytest.raises(UserError, match="width 8 but the labelled ones 32"):
        gate.choose(view(features[:, :8], learner, labelled, gen())).mask
    with pytest.raises(UserError, match=r"learner actions must be torch.int64 \(200,\)"):
        gate.choose(view(features, learner.float(), labelled, gen())).mask
    with pytest.raises(UserError, match="k = 61 needs at least 61 labelled states, got 60"):
        NoveltyGate(quantile=0.5, k=61).choose(view(features, learner, labelled, gen())).mask
    with pytest.raises(UserError, match="learner_actions must be laid out as the labels"):
        Labelled(labelled.features, labelled.labels, labelled.labels[:5])
    with pytest.raises(UserError, match=r"Labelled.labels must be int64 \[M\] or float32 \[M, d\]"):
        Labelled(labelled.features, labelled.labels.double(), labelled.labels.double())


@both
def test_the_oracle_labels_exactly_the_states_where_the_learner_is_wrong(discrete):
    features, learner, labelled = mismatch_scene(discrete)
    expert = learner.clone()
    wrong = torch.zeros(len(features), dtype=torch.bool)
    wrong[::7] = True
    expert[wrong] = actions(torch.ones(int(wrong.sum()), dtype=torch.int64), discrete)
    chosen = make_gate("oracle", 0.0).choose(view(features, learner, labelled, gen(), expert_labels=expert))
    assert torch.equal(chosen.mask, wrong)  # at 0 every wrong state, and nothing else
    assert torch.equal(chosen.scores > 0, wrong)
    if not discrete:  # with action vectors a higher setting keeps the larger errors only
        expert[wrong] = expert[wrong] * torch.arange(1, int(wrong.sum()) + 1).float()[:, None]
        top = make_gate("oracle", 0.5).choose(view(features, learner, labelled, gen(), expert_labels=expert))
        assert top.mask.sum() < wrong.sum() and (top.mask & ~wrong).sum() == 0
    with pytest.raises(UserError, match="OracleGate reads the expert's labels of the round's states"):
        make_gate("oracle", 0.0).choose(view(features, learner, labelled, gen()))


@both
def test_score_gates_report_the_scores_they_chose_by(discrete):
    features, learner, labelled = mismatch_scene(discrete)
    for name in ("ensemble", "safe", "novelty", "conformal"):
        chosen = make_gate(name, 0.5).choose(view(features, learner, labelled, gen()))
        assert chosen.scores is not None and chosen.scores.shape == (len(features),)
        assert torch.equal(chosen.mask, make_gate(name, 0.5).choose(view(features, learner, labelled, gen())).mask)
    assert make_gate("random", 0.5).choose(view(features, learner, labelled, gen())).scores is None


@both
def test_the_disagreement_gate_labels_where_the_two_heads_act_apart(discrete):
    """Equal heads label nothing; otherwise the states above the round's quantile of the heads'
    total variation distance (class distributions) or squared distance (actions) are labelled."""
    from metadagger.imitation.reading_gates import DisagreementGate, head_disagreement

    outputs = 3 if discrete else 2
    features, learner, labelled = scene(discrete)
    current = _heads(F, outputs, 3)
    gate = DisagreementGate(0.5)
    same = gate.choose(view(features, learner, labelled, gen(), head=current, reference=current.clone()))
    assert not same.mask.any() and torch.equal(same.scores, torch.zeros(len(features), dtype=torch.float64))
    reference = _heads(F, outputs, 4)
    chosen = gate.choose(view(features, learner, labelled, gen(), head=current, reference=reference))
    expected = head_disagreement(view(features, learner, labelled, gen(), head=current, reference=reference))
    assert torch.equal(chosen.scores, expected) and torch.equal(chosen.mask, above_quantile(expected, 0.5))

    def out(head: torch.Tensor) -> torch.Tensor:
        weight, bias = head[: outputs * F].view(outputs, F), head[outputs * F :]
        return features.double() @ weight.double().T + bias.double()

    if discrete:
        direct = 0.5 * (out(current).softmax(dim=1) - out(reference).softmax(dim=1)).abs().sum(dim=1)
        assert float(expected.min()) >= 0.0 and float(expected.max()) <= 1.0
    else:
        direct = (out(current) - out(reference)).square().sum(dim=1)
    assert torch.allclose(expected, direct)


def test_the_disagreement_gate_needs_a_reference_head_of_the_learners_layout():
    from metadagger.imitation.reading_gates import DisagreementGate

    features, learner, labelled = scene(True)
    with pytest.raises(UserError, match="DisagreementGate compares the learner's head with a reference head"):
        DisagreementGate(0.5).choose(view(features, learner, labelled, gen()))
    with pytest.raises(UserError, match=r"the reference head must be laid out as the learner's \(99,\)"):
        view(features, learner, labelled, gen(), reference=torch.zeros(98))
    with pytest.raises(UserError, match=r"DisagreementGate.quantile must be in \[0, 1\)"):
        DisagreementGate(1.0)


def test_uncertainty_scores_are_least_confidence_margin_and_entropy_of_the_class_distribution():
    from metadagger.imitation.uncertainty_gates import entropy, least_confidence, margin

    p = torch.tensor([[1.0, 0.0, 0.0], [0.5, 0.3, 0.2], [1 / 3, 1 / 3, 1 / 3]], dtype=torch.float64)
    assert torch.allclose(least_confidence(p), torch.tensor([0.0, 0.5, 2 / 3], dtype=torch.float64))
    assert torch.allclose(margin(p), torch.tensor([0.0, 0.8, 1.0], dtype=torch.float64))
    h = -(0.5 * torch.tensor(0.5).log() + 0.3 * torch.tensor(0.3).log() + 0.2 * torch.tensor(0.2).log())
    expected = torch.tensor([0.0, float(h), float(torch.tensor(3.0).log())], dtype=torch.float64)
    assert torch.allclose(entropy(p), expected)


@pytest.mark.parametrize("name", ["least-confidence", "margin", "entropy"])
def test_uncertainty_gates_label_where_the_learners_own_classes_are_unsure(name):
    """A head sure of its class on the labelled blobs and unsure far from them: far states are labelled,
    whatever the features' scale; the scores are the measure of softmax(logits), above the round's quantile."""
    features, learner, labelled = scene(True)
    # logits: the features' projections on the three blob centres, sharp near a centre and flat far away
    centres = torch.stack([labelled.features[labelled.labels == c].mean(dim=0) for c in range(3)])
    sharp = 10 * centres / centres.norm(dim=1, keepdim=True) ** 2
    head = torch.cat([sharp.flatten(), torch.zeros(3)]).float()
    far_flat = features.clone()
    far_flat[N_NEAR:] *= 0.01  # far states shrunk toward 0: their logits near equal
    chosen = make_gate(name, 0.5).choose(view(far_flat, learner, labelled, gen(), head=head))
    assert chosen.mask[N_NEAR:].all() and not chosen.mask[:N_NEAR].any()
    p = (far_flat.double() @ head[:-3].view(3, F).double().T).softmax(dim=1)
    assert torch.allclose(chosen.scores, make_gate(name, 0.5).measure(p))


def test_a_plug_in_gate_that_reads_a_reference_head_is_refused_at_its_declaration():
    from metadagger.imitation.gate_registry import GateDeclaration
    from metadagger.imitation.reading_gates import DisagreementGate

    with pytest.raises(UserError, match=r"reads a reference head, which the benchmark hands only to MetaL DAgger's"):
        GateDeclaration("mine", DisagreementGate, "DAgger, mine", (0.5,), "compares heads")


def test_gates_of_class_distributions_are_refused_on_action_vectors_naming_those_that_serve():
    from metadagger.imitation.gate_registry import check_gates_serve

    check_gates_serve(["dagger-entropy", "dagger-safe"], discrete=True, task="carracing")
    with pytest.raises(UserError) as refused:
        check_gates_serve(["dagger-safe", "dagger-margin", "dagger-entropy"], discrete=False, task="fetch")
    assert str(refused.value).startswith(
        "benchmark method(s) dagger-margin, dagger-entropy read the learner's class distribution, but task fetch acts "
        "with action vectors; drop them, or use a gate that serves it: dagger-random, dagger-ensemble, dagger-safe"
    )


@both
@pytest.mark.parametrize("name", sorted(gate_declarations()))
def test_no_gate_calls_a_kernel_whose_bits_depend_on_the_cpu(name, discrete):
    """A gate's scores decide which states are labelled, so each gate (the oracle too) computes them
    with kernels the pins fix on every x86-64 CPU: none of MKL's vector math (docs/determinism.md)."""
    declaration = gate_declarations()[name]
    if declaration.gate.needs_classes and not discrete:
        return  # refused on action vectors: test_each_gate_returns_a_bool_mask_per_state
    features, learner, labelled = mismatch_scene(discrete)
    reads = {"expert_labels": learner.clone()} if declaration.reference else {}
    gate = make_gate(name, declaration.grid[1])
    assert mkl_vector_math_calls(lambda: gate.choose(view(features, learner, labelled, gen(), **reads))) == []
