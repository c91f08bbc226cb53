"""Lockstep lanes: an episode is the same whichever episodes share its steps; chains run in lanes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from toy_task import CorridorTask

from metadagger.errors import UserError
from metadagger.imitation.data import images_kept, take_rows
from metadagger.imitation.early_stop import CosineEarlyStop
from metadagger.imitation.features import FeatureCache
from metadagger.imitation.lanes import SHAPE_STEP, EpisodeRequest, Lanes, run_chains
from metadagger.imitation.rollouts import Trajectory, rollout
from metadagger.policies import make_policy
from metadagger.utils.kernels import mkl_vector_math_calls

SEEDS = (0, 1, 2, 3, 4, 5)


def _heads(task, n: int) -> list[np.ndarray]:
    return [make_policy(task, seed=10 + i).head_vector().numpy() for i in range(n)]


def _same(a: Trajectory, b: Trajectory, *, features: bool = True, images: bool = True) -> None:
    for name in ("obs", "expert_labels", "learner_actions", "step_rewards", "final_obs")[0 if images else 1 :]:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert (a.reward, a.steps, a.success, a.terminated, a.early_stopped, a.seed) == (
        b.reward,
        b.steps,
        b.success,
        b.terminated,
        b.early_stopped,
        b.seed,
    )
    if features:
        np.testing.assert_array_equal(a.features, b.features)


@pytest.mark.parametrize("discrete", [True, False])
def test_a_lane_acts_with_its_head_on_its_row_of_the_padded_batch(discrete):
    """Each step's action is the lane's head applied to the trunk's output on a batch of exactly
    ``width`` rows (the others zero), and those features are the ones the trajectory keeps."""
    task = CorridorTask(discrete=discrete)
    policy = make_policy(task, seed=3)
    with Lanes(task, policy.net, width=3) as lanes:
        [laned] = lanes.run([EpisodeRequest(SEEDS[0], policy.head_vector().numpy(), keep_images=True)])
    batch = np.zeros((len(laned.obs), 3, *laned.obs.shape[1:]), np.uint8)
    batch[:, 0] = laned.obs
    for t, padded in enumerate(batch):
        with torch.inference_mode():
            features = policy.net.features(torch.from_numpy(padded))[:1]
            out = policy.net.head(features)
        np.testing.assert_array_equal(laned.features[t : t + 1], features.numpy())
        action = out.argmax(dim=1).numpy() if discrete else out.numpy()
        np.testing.assert_array_equal(laned.learner_actions[t : t + 1], action)
    env = task.make_env()
    alone = rollout(env, seed=SEEDS[0], policy=policy)  # batch 1: the same episode up to the last bits
    env.close()
    assert alone.steps == laned.steps and np.allclose(alone.learner_actions, laned.learner_actions, atol=1e-5)


def test_an_episode_does_not_depend_on_the_episodes_beside_it_nor_on_its_lane():
    task = CorridorTask(discrete=True)
    net = make_policy(task, seed=3).net
    heads = _heads(task, len(SEEDS))
    requests = [EpisodeRequest(seed, head, keep_images=True) for seed, head in zip(SEEDS, heads)]
    with Lanes(task, net, width=4) as lanes:
        together = lanes.run(requests)
        backwards = lanes.run(requests[::-1])[::-1]
        alone = [lanes.run([request])[0] for request in requests]
        assert lanes.forwards > 0
    for a, b, c in zip(together, backwards, alone):
        _same(a, b)
        _same(a, c)
    assert len({t.steps for t in together}) > 1, "episodes of different lengths: lanes were refilled mid-run"


def test_the_expert_drives_a_lane_without_a_head_and_early_stops_and_caps_cut_as_alone():
    task = CorridorTask(discrete=False)
    policy = make_policy(task, seed=3)
    env = task.make_env()
    demo = rollout(env, seed=1, policy=None)
    env.close()
    head = policy.head_vector().numpy()
    with Lanes(task, policy.net, width=3) as lanes:
        got = lanes.run(
            [
                EpisodeRequest(1, None, keep_images=True),
                EpisodeRequest(1, head, early_stop=0.5, keep_images=True),
                EpisodeRequest(2, head, max_steps=2, keep_images=True),
            ]
        )
    _same(demo, got[0], features=False)
    assert got[0].features.shape == (demo.steps, policy.net.feature_dim) and got[0].features.dtype == np.float32
    stopped, capped = got[1], got[2]
    stop = CosineEarlyStop(threshold=0.5)
    fired = [stop.update(a, b) for a, b in zip(stopped.learner_actions, stopped.expert_labels)]
    assert stopped.early_stopped and not stopped.success and fired == [False] * (stopped.steps - 1) + [True]
    assert capped.steps == 2 and not capped.success and not capped.early_stopped


def test_lanes_refuse_a_bad_width():
    task = CorridorTask()
    with pytest.raises(ValueError, match="width >= 1"):
        Lanes(task, make_policy(task, seed=0).net, width=0)


def _chain(seeds: tuple[int, ...], head: np.ndarray):
    """A chain that rolls its seeds one after another, each episode's length shifting the next head."""

    def body(lane):
        out, shifted = [], head.copy()
        for seed in seeds:
            trajectory = lane.roll(EpisodeRequest(seed, shifted, keep_images=True))
            out.append(trajectory)
            shifted = shifted + np.float32(0.01 * trajectory.steps)
        return out

    return body


def test_chains_give_what_each_gives_alone_in_any_order_and_any_width():
    task = CorridorTask(discrete=True)
    net = make_policy(task, seed=3).net
    heads = _heads(task, 4)
    plans = [((0, 1, 2), heads[0]), ((3,), heads[1]), ((4, 5), heads[2]), ((1, 3, 5, 0), heads[3])]
    with Lanes(task, net, width=3) as lanes:
        together = run_chains(lanes, [_chain(*plan) for plan in plans])
        backwards = run_chains(lanes, [_chain(*plan) for plan in plans[::-1]])[::-1]
        alone = [run_chains(lanes, [_chain(*plan)])[0] for plan in plans]
    with Lanes(task, net, width=3) as other:
        again = run_chains(other, [_chain(*plan) for plan in plans])
    for runs in (backwards, alone, again):
        for mine, theirs in zip(together, runs):
            assert len(mine) == len(theirs)
            for a, b in zip(mine, theirs):
                _same(a, b)


def test_a_failing_chain_stops_the_others_and_its_error_reaches_the_caller():
    task = CorridorTask(discrete=True)
    net = make_policy(task, seed=3).net
    head = _heads(task, 1)[0]
    finished = []

    def failing(lane):
        lane.roll(EpisodeRequest(0, head))
        raise UserError("a chain's own error")

    def long(lane):
        for seed in SEEDS:
            lane.roll(EpisodeRequest(seed, head))
        finished.append(True)

    with Lanes(task, net, width=2) as lanes:
        with pytest.raises(UserError, match="a chain's own error"):
            run_chains(lanes, [long, failing, long])
    assert finished == []


def test_a_laned_episode_keeps_its_features_and_no_image_unless_asked():
    task = CorridorTask(discrete=True)
    policy = make_policy(task, seed=3)
    head = policy.head_vector().numpy()
    with Lanes(task, policy.net, width=2) as lanes:
        kept, bare = lanes.run([EpisodeRequest(1, head, keep_images=True), EpisodeRequest(1, head)])
    _same(kept, bare, images=False)
    assert images_kept(kept.obs) and not images_kept(bare.obs)
    assert bare.obs.shape == kept.obs.shape and bare.obs.base.nbytes == 1  # one byte, whatever the length
    assert not images_kept(take_rows(bare.obs, np.arange(len(bare.obs)) % 2 == 0))
    data = bare.to_dataset()
    np.testing.assert_array_equal(FeatureCache(policy).features_of(data).numpy(), kept.features)
    with pytest.raises(RuntimeError, match="not kept"):
        FeatureCache(policy).features(bare.obs)


class _LongCorridor(CorridorTask):
    max_episode_steps = 600  # longer than a lane's first buffer of features


def test_a_long_laned_episode_keeps_every_steps_features():
    task = _LongCorridor(discrete=True)
    policy = make_policy(task, seed=3)
    with Lanes(task, policy.net, width=2) as lanes:
        long, short = lanes.run([EpisodeRequest(1, None, keep_images=True), EpisodeRequest(2, None, max_steps=5)])
    assert long.steps == 600 and long.features.shape == (600, policy.net.feature_dim) and len(short.features) == 5
    np.testing.assert_array_equal(FeatureCache(policy).features_of(long.to_dataset()).numpy(), long.features)
    assert long.features.base is None  # its own array, not a view of the lane's buffer


def test_few_live_lanes_step_in_a_smaller_batch_only_where_it_gives_the_widths_bits():
    """With 16 lanes, a step with few live lanes runs the trunk on 8 or 12 rows where that shape
    gives every row the width's bits; the episodes are those of the full width, bit for bit."""
    task = CorridorTask(discrete=True)
    net = make_policy(task, seed=3).net
    requests = [EpisodeRequest(seed, head, keep_images=True) for seed, head in zip(SEEDS, _heads(task, len(SEEDS)))]
    with Lanes(task, net, width=16) as lanes:
        assert lanes.shapes[-1] == 16 and all(s % SHAPE_STEP == 0 for s in lanes.shapes)
        cut = lanes.run(requests)
        lanes.shapes = [16]  # every step at the width, each lane in its own row
        whole = lanes.run(requests)
    for a, b in zip(cut, whole):
        _same(a, b)


def test_a_trunk_whose_rows_depend_on_their_place_keeps_the_width_and_each_lanes_row():
    """A trunk that computes a tail of the batch otherwise (here: the last row scaled) fails the
    check: every step then runs at the width, each lane in its own row."""
    task = CorridorTask(discrete=True)
    net = make_policy(task, seed=3).net
    plain = net.trunk

    class TailOtherwise(torch.nn.Module):
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            out = plain(x).clone()
            out[-1] *= 1.0000001
            return out

    net.trunk = TailOtherwise()
    with Lanes(task, net, width=16) as lanes:
        assert lanes.shapes == [16]
    net.trunk = plain
    with Lanes(task, net, width=SHAPE_STEP) as lanes:
        assert lanes.shapes == [SHAPE_STEP]  # no smaller shape is tried


@pytest.mark.parametrize("task_name", ["carracing", "carracing-family", "fetch", "fetch-family"])
def test_every_packaged_width_gives_a_row_the_same_bits_in_any_place(task_name):
    """At every lane width a packaged preset sets, and at 8 and 16 (what a user who turns lanes on
    where a preset keeps 1 is pointed to), the task's trunk gives an image the same bits in any row
    of the batch (here: the batch reversed), so an episode never depends on its lane; at a width of
    10 or 15 the pinned kernels compute the last rows otherwise (docs/performance.md)."""
    from metadagger.pipeline.run_config import PRESETS, resolve_config
    from metadagger.tasks import make_task

    if task_name.startswith("fetch"):
        pytest.importorskip("mujoco", reason="the fetch extra is not installed")
    task = make_task(task_name)
    net = make_policy(task, seed=0).net
    widths = {8, 16}
    for preset in PRESETS:
        config = resolve_config(task_name, preset)
        stages = (config.pistar, config.pairs, config.evaluate, config.mdi, config.benchmark)
        widths |= {stage.lanes for stage in stages if stage is not None}
    for width in sorted(widths - {1}):
        lanes = Lanes(task, net, width=width)
        probe = np.random.default_rng(width).integers(0, 256, size=lanes._batch.shape, dtype=np.uint8)
        with torch.inference_mode():
            rows = lanes._features(probe)
            reversed_rows = lanes._features(probe[::-1].copy())
        assert torch.equal(reversed_rows, rows.flip(0)), f"{task_name}: width {width}"


@pytest.mark.parametrize("task_name", ["carracing", "fetch"])
def test_laned_episodes_call_no_kernel_whose_bits_depend_on_the_cpu(task_name):
    """The lanes' steps on each packaged task (its trunk on a padded batch, each lane's head on its
    row, the expert driving a lane, lanes ending and refilled) reach none of MKL's vector math,
    whose bits depend on the CPU (docs/determinism.md)."""
    from metadagger.tasks import make_task

    if task_name.startswith("fetch"):
        pytest.importorskip("mujoco", reason="the fetch extra is not installed")
    task = make_task(task_name)
    policy = make_policy(task, seed=0)
    heads = [None, policy.head_vector().numpy(), make_policy(task, seed=1).head_vector().numpy()]
    requests = [EpisodeRequest(seed, head, max_steps=3 + seed) for seed, head in enumerate(heads)]
    with Lanes(task, policy.net, width=2) as lanes:
        assert mkl_vector_math_calls(lambda: lanes.run(requests)) == []


def test_a_perturbed_expert_episode_in_a_lane_is_the_one_rolled_out_alone():
    from metadagger.imitation.rollouts import ActionNoise

    task = CorridorTask(discrete=True)
    net = make_policy(task, seed=3).net
    noise = [ActionNoise(0.3, stream=(seed, 0)) for seed in SEEDS[:3]]
    with Lanes(task, net, width=2) as lanes:
        laned = lanes.run([EpisodeRequest(seed, None, noise=n) for seed, n in zip(SEEDS, noise)])
    env = task.make_env()
    for seed, n, episode in zip(SEEDS, noise, laned):
        _same(episode, rollout(env, seed=seed, policy=None, noise=n), features=False, images=False)
    env.close()
    assert any((e.learner_actions != e.expert_labels).any() for e in laned)
