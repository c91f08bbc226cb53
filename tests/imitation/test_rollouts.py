"""Rollouts and collect on the toy corridor task."""

from __future__ import annotations

import numpy as np
import pytest
from toy_task import TOY_ARCH, CorridorTask

from metadagger.imitation.collect import collect
from metadagger.imitation.early_stop import CosineEarlyStop
from metadagger.imitation.rollouts import rollout
from metadagger.policies import make_policy


@pytest.mark.filterwarnings("ignore:.*different from the unwrapped")
def test_toy_task_env_passes_gymnasium_checks(task):
    from gymnasium.utils.env_checker import check_env

    check_env(task.make_env(), skip_render_check=True)


def test_expert_demo_succeeds_and_counts_queries(task):
    (demo,) = collect(task, [3], policy=None)
    assert demo.success and demo.steps == task.max_episode_steps
    assert demo.expert_queries == demo.steps == len(demo.obs) == len(demo.expert_labels)
    assert demo.obs.dtype == np.uint8 and demo.obs.shape[1:] == (16, 16, 3)
    np.testing.assert_array_equal(demo.learner_actions, demo.expert_labels)
    assert demo.reward == task.max_episode_steps and demo.seed == 3
    expected = np.int64 if task.is_discrete else np.float32
    assert demo.expert_labels.dtype == expected and demo.to_dataset().labels.dtype == expected


def test_rollouts_are_deterministic_per_seed(task, policy):
    first, second = collect(task, [5, 5], policy=policy)
    np.testing.assert_array_equal(first.obs, second.obs)
    np.testing.assert_array_equal(first.learner_actions, second.learner_actions)


def test_learner_rollout_records_expert_labels_of_visited_states(discrete_task):
    policy = make_policy(discrete_task, seed=1, **TOY_ARCH)
    env = discrete_task.make_env()
    traj = rollout(env, seed=0, policy=policy)
    np.testing.assert_array_equal(traj.learner_actions, policy.act_batch(traj.obs))
    # replay the visited states: the recorded label is the expert's label for each observation
    obs, info = env.reset(seed=0)
    for t in range(traj.steps):
        np.testing.assert_array_equal(obs, traj.obs[t])
        assert info["expert_label"] == traj.expert_labels[t]
        obs, _, _, _, info = env.step(int(traj.learner_actions[t]))
    assert traj.expert_queries == traj.steps


class StopAfter:
    """Early stop that fires on the n-th disagreement with the expert."""

    def __init__(self, n: int):
        self.n, self.count, self.resets = n, 0, 0

    def reset(self) -> None:
        self.count, self.resets = 0, self.resets + 1

    def update(self, learner_action, expert_label) -> bool:
        self.count += int(np.any(learner_action != expert_label))
        return self.count >= self.n


def test_early_stop_fires_and_counts_as_failure(discrete_task):
    always_left = make_policy(discrete_task, seed=0, **TOY_ARCH)
    always_left.act_batch = lambda obs: np.zeros(len(obs), np.int64)  # a learner that disagrees often
    stop = StopAfter(2)
    traj = rollout(discrete_task.make_env(), seed=0, policy=always_left, early_stop=stop)
    assert traj.early_stopped and not traj.success
    assert stop.resets == 1 and stop.count == 2
    assert traj.steps == traj.expert_queries == len(traj.obs) < discrete_task.max_episode_steps
    assert int(np.sum(traj.learner_actions != traj.expert_labels)) == 2

    trajs = collect(discrete_task, [0, 1], policy=always_left, early_stop_factory=lambda: StopAfter(100))
    assert not any(t.early_stopped for t in trajs)


def test_max_steps_caps_an_episode_without_success():
    task = CorridorTask(discrete=True)
    traj = rollout(task.make_env(), seed=0, policy=None, max_steps=5)
    assert traj.steps == 5 and not traj.success
    with pytest.raises(ValueError, match="max_steps"):
        rollout(task.make_env(), seed=0, policy=None, max_steps=0)


def test_make_policy_reads_the_task(task):
    policy = make_policy(task, seed=0, **TOY_ARCH)
    assert policy.arch["obs_shape"] == [16, 16, 3]
    assert policy.arch["n_outputs"] == task.label_dim() and policy.discrete == task.is_discrete
    assert policy.task == task.name
    assert make_policy(task, seed=0, **TOY_ARCH).head_vector().equal(policy.head_vector())
    with pytest.raises(ValueError, match="unknown architecture option"):
        make_policy(task, seed=0, width=3)


def test_a_process_pool_gives_the_same_trajectories_in_seed_order(task, policy):
    seeds = [7, 2, 9, 4, 1, 8, 3, 6, 5]  # more seeds than chunks of one worker, not sorted
    alone = collect(task, seeds, policy=policy)
    pooled = collect(task, seeds, policy=policy, workers=2)
    assert [t.seed for t in pooled] == seeds
    for a, b in zip(alone, pooled):
        np.testing.assert_array_equal(a.obs, b.obs)
        np.testing.assert_array_equal(a.learner_actions, b.learner_actions)
        np.testing.assert_array_equal(a.expert_labels, b.expert_labels)
        assert (a.reward, a.success) == (b.reward, b.success)


def test_evaluation_rows_are_made_where_the_episodes_run(task, policy):
    from metadagger.imitation.episodes import episode_row, evaluate_policy

    seeds = [3, 1, 2]
    rows = evaluate_policy(task, policy, seeds, progress=False, workers=2)
    assert rows == [episode_row(t) for t in collect(task, seeds, policy=policy)]
    assert [r["seed"] for r in rows] == seeds


def test_episodes_in_lanes_do_not_depend_on_the_pool_nor_on_their_lane_mates(task, policy):
    seeds = [7, 2, 9, 4, 1, 8, 3, 6, 5]
    laned = collect(task, seeds, policy=policy, lanes=4)
    pooled = collect(task, seeds, policy=policy, lanes=4, workers=2)
    alone = [collect(task, [seed], policy=policy, lanes=4)[0] for seed in seeds]
    unlaned = collect(task, seeds, policy=policy)
    assert [t.seed for t in laned] == seeds
    for a, b, c, d in zip(laned, pooled, alone, unlaned):
        assert a.features is None  # the features belong to the trunk of the moment; the images stay
        for other in (b, c):
            np.testing.assert_array_equal(a.obs, other.obs)
            np.testing.assert_array_equal(a.learner_actions, other.learner_actions)
            assert (a.reward, a.success, a.steps) == (other.reward, other.success, other.steps)
        np.testing.assert_array_equal(a.obs[0], d.obs[0])  # the same seed's episode, acted on at another batch shape
    with pytest.raises(ValueError, match="early stop"):
        collect(task, seeds, policy=policy, lanes=4, early_stop_factory=CosineEarlyStop)


def test_dart_noise_perturbs_what_the_expert_executes_not_what_it_labels(task):
    """With classes, about ``scale`` of the steps execute another class; with vectors, every
    coordinate is off by noise of that scale (within the action space); each state's label is the
    expert's own action there; the same stream gives the same episode, another stream another one."""
    from metadagger.imitation.rollouts import ActionNoise

    env = task.make_env()
    clean = rollout(env, seed=0, policy=None)
    noisy = rollout(env, seed=0, policy=None, noise=ActionNoise(0.3, stream=(0, 0)))
    again = rollout(env, seed=0, policy=None, noise=ActionNoise(0.3, stream=(0, 0)))
    other = rollout(env, seed=0, policy=None, noise=ActionNoise(0.3, stream=(0, 1)))
    quiet = rollout(env, seed=0, policy=None, noise=ActionNoise(0.0, stream=(0, 0)))
    np.testing.assert_array_equal(noisy.learner_actions, again.learner_actions)
    assert not np.array_equal(noisy.learner_actions, other.learner_actions)
    np.testing.assert_array_equal(quiet.learner_actions, clean.learner_actions)
    off = noisy.learner_actions != noisy.expert_labels
    if task.is_discrete:
        assert 0.1 < off.mean() < 0.5, off.mean()
    else:
        space = env.action_space
        inside = ((noisy.learner_actions > space.low) & (noisy.learner_actions < space.high)).all(axis=1)
        assert inside.mean() > 0.5 and off[inside].all()  # noise on every coordinate but where clipped
        assert (noisy.learner_actions >= space.low).all() and (noisy.learner_actions <= space.high).all()
    # replaying the executed actions visits the same states, where the expert's label is the one recorded
    _, info = env.reset(seed=0)
    for label, executed in zip(noisy.expert_labels, noisy.learner_actions):
        np.testing.assert_array_equal(info["expert_label"], label)
        info = env.step(executed)[4]
    env.close()
    with pytest.raises(ValueError, match="pass policy=None"):
        rollout(task.make_env(), seed=0, policy=make_policy(task, seed=0, **TOY_ARCH), noise=ActionNoise(0.1, (0,)))
    if task.is_discrete:
        with pytest.raises(ValueError, match="a probability in \\[0, 1\\], got 1.5"):
            rollout(task.make_env(), seed=0, policy=None, noise=ActionNoise(1.5, (0,)))
