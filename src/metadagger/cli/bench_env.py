"""``bench env``: our base env's steps per second against upstream's on the same seeds and actions,
or the Fetch pixel env's frames per second."""

from __future__ import annotations

import time
from typing import Any, Sequence

import gymnasium as gym
import numpy as np

from metadagger.cli.bench import machine_block
from metadagger.errors import UserError
from metadagger.tasks.gym_ids import register_envs

#: task -> (our base env id, the upstream id it reproduces)
ENV_PAIRS = {
    "carracing": ("metadagger/CarRacing-v0", "CarRacing-v3"),
    # the echo band on our CarRacing, against our CarRacing: what the band costs a step
    "carracing-echo": ("metadagger/CarRacing-v0+echo", "metadagger/CarRacing-v0"),
    # the variant carracing-echo's presets run (its task_options), against our CarRacing
    "carracing-echo-faults": ("metadagger/CarRacing-v0+faults", "metadagger/CarRacing-v0"),
}


def smooth_actions(seed: int, steps: int) -> np.ndarray:
    """A seeded, random but smooth CarRacing action sequence, shape (steps, 3), float32.

    Steering follows an AR(1) process (so the car weaves, and sometimes leaves the road), gas
    is mostly on and the brake is tapped now and then.
    """
    rng = np.random.default_rng(seed)
    actions = np.zeros((steps, 3), dtype=np.float32)
    steer = 0.0
    for i in range(steps):
        steer = float(np.clip(0.9 * steer + 0.25 * rng.normal(), -1.0, 1.0))
        gas = 0.5 if rng.random() < 0.7 else 0.0
        brake = 0.3 if rng.random() < 0.05 else 0.0
        actions[i] = (steer, gas, brake)
    return actions


def bench_env(
    task: str = "carracing", *, seeds: Sequence[int] = (0, 1, 2), steps: int = 1000, warmup_steps: int = 100
) -> dict:
    """Step our base env and upstream's on the same seeds and actions; return both rates.

    Both envs are built with ``gym.make`` (same wrappers) and take turns, 50 steps at a time,
    on the same seeds and actions, so load from other processes falls on both alike.
    Only ``step`` is timed (not ``reset``); an episode that ends early is reset with the same
    seed and continues. First, ``warmup_steps`` untimed steps run on a seed outside ``seeds``
    (imports, fonts, and our renderer's small caches of reward-text and indicator patches,
    which any longer run keeps warm).

    Args:
        task: the task whose base env to time: ``"carracing"`` (ours against upstream's),
            ``"carracing-echo"`` (our CarRacing with the echo band against our CarRacing; the
            ``upstream`` entry is then ours without the band), ``"carracing-echo-faults"`` (the
            variant carracing-echo's presets run, its faults and band, against our CarRacing:
            its rewards may differ, since a fault moves the car), or ``"fetch"`` (frames per second
            of our pixel env alone, random actions).
        seeds: reset seeds, one episode each.
        steps: timed steps per seed.
        warmup_steps: untimed steps before timing.

    Returns:
        A JSON-ready dict: per env its id, steps/s, mean and median time per step and the
        per-step time split (state rendering vs the rest: physics, rewards, wrappers); the
        ratio of rates and the ratio of median step times (robust to the other processes'
        preemptions on a busy machine); whether both envs gave identical rewards; the mean
        absolute image difference per seed (0-255 scale, averaged over the frames); the seeds,
        steps and machine info.
    """
    if steps <= 0 or not seeds:
        raise UserError(f"bench env needs steps > 0 and at least one seed, got steps={steps}, seeds={list(seeds)}")
    if task == "fetch":
        return _bench_fetch(seeds, steps)
    if task not in ENV_PAIRS:
        raise UserError(
            f"bench env: unknown task {task!r}: expected one of {', '.join([*ENV_PAIRS, 'fetch'])}; pass --task "
            "carracing"
        )
    ids = ENV_PAIRS[task]
    register_envs()  # our id, for gym.make
    envs = [_TimedEnv(env_id) for env_id in ids]
    try:
        if warmup_steps > 0:
            _lockstep(envs, max(seeds) + 1, smooth_actions(max(seeds) + 1, warmup_steps))
            for env in envs:
                env.step_s = env.render_s = 0.0
                env.step_times.clear()
        same_rewards = True
        image_mae = {}
        for seed in seeds:
            (ours, upstream), (ours_obs, upstream_obs) = _lockstep(envs, seed, smooth_actions(seed, steps))
            same_rewards &= bool(np.array_equal(ours, upstream))
            image_mae[str(seed)] = float(np.abs(ours_obs.astype(np.int16) - upstream_obs).mean())
    finally:
        for env in envs:
            env.close()
    n = steps * len(seeds)
    ours, upstream = (env.summary(n) for env in envs)
    return {
        "task": task,
        "ours": ours,
        "upstream": upstream,
        "ratio": ours["steps_per_s"] / upstream["steps_per_s"],
        "ratio_of_medians": upstream["median_us_per_step"] / ours["median_us_per_step"],
        "identical_rewards": same_rewards,
        "image_mae": image_mae,
        "seeds": [int(s) for s in seeds],
        "steps": int(steps),
        "warmup_steps": int(warmup_steps),
        "machine": machine_block(),
    }


def _bench_fetch(seeds: Sequence[int], steps: int) -> dict:
    """Frames per second of the Fetch pixel env (every step renders; there is no fast/slow pair
    to compare: upstream renders the same scene with anti-aliasing, see docs/fetch.md)."""
    try:
        from metadagger.tasks.fetch.env import bench_fetch_env
    except ImportError as exc:
        raise UserError(
            f"bench env --task fetch needs the fetch extra ({exc}); pip install -c constraints.txt -e '.[fetch]'"
        ) from None
    return {"task": "fetch", **bench_fetch_env(seeds=list(seeds), steps=steps), "machine": machine_block()}


class _TimedEnv:
    """A ``gym.make`` env that adds up the seconds spent in ``step`` and in state rendering."""

    def __init__(self, env_id: str):
        self.env_id = env_id
        base_id, _, wrapper = env_id.partition("+")
        self.env = gym.make(base_id)
        if wrapper:  # carracing-echo's wrappers: its default band (echo), or its presets' variant (faults)
            from metadagger.pipeline.run_config import load_preset
            from metadagger.tasks.carracing_echo.task import CarRacingEchoTask

            options = load_preset("carracing-echo", "quick")["task_options"] if wrapper == "faults" else {}
            self.env = CarRacingEchoTask(**options).wrap(self.env)
        self.step_s = 0.0
        self.render_s = 0.0
        self.step_times: list[float] = []
        base = self.env.unwrapped
        render = base._render

        def timed_render(mode: str):
            start = time.perf_counter()
            out = render(mode)
            self.render_s += time.perf_counter() - start
            return out

        # Instrument the instance (not the class): step() calls self._render("state_pixels").
        base._render = timed_render

    def reset(self, seed: int) -> None:
        render_s = self.render_s
        self.env.reset(seed=seed)
        self.render_s = render_s  # reset's own render is not a step's

    def step(self, action: np.ndarray) -> tuple[float, bool, np.ndarray]:
        start = time.perf_counter()
        obs, reward, terminated, truncated, _ = self.env.step(action)
        elapsed = time.perf_counter() - start
        self.step_s += elapsed
        self.step_times.append(elapsed)
        return float(reward), bool(terminated or truncated), obs

    def summary(self, n: int) -> dict[str, Any]:
        return {
            "id": self.env_id,
            "steps_per_s": n / self.step_s,
            "us_per_step": 1e6 * self.step_s / n,
            "median_us_per_step": 1e6 * float(np.median(self.step_times[-n:])),
            "render_us_per_step": 1e6 * self.render_s / n,
            "other_us_per_step": 1e6 * (self.step_s - self.render_s) / n,
        }

    def close(self) -> None:
        self.env.close()


def _lockstep(envs: list[_TimedEnv], seed: int, actions: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Run one seeded episode per env, alternating chunks of steps; returns each env's rewards
    and observations."""
    rewards = [np.zeros(len(actions)) for _ in envs]
    frames = [np.zeros((len(actions), *env.env.observation_space.shape), np.uint8) for env in envs]
    for env in envs:
        env.reset(seed)
    for start in range(0, len(actions), _CHUNK):
        for env, out, obs in zip(envs, rewards, frames):
            for i in range(start, min(start + _CHUNK, len(actions))):
                out[i], done, obs[i] = env.step(actions[i])
                if done:
                    env.reset(seed)
    return rewards, frames


#: Steps each env runs before the other takes over. Alternating every step would let upstream's
#: 1000x800 surfaces evict our data from the CPU caches each time (measured: ours ran 2.5x
#: slower); chunks of this size keep that cost small while both still share the machine's load.
_CHUNK = 50
