"""Experts for FetchPickAndPlace that read the simulator state.

:class:`FetchExpert` is a scripted controller and a pure function of the current state (no
memory), so DAgger can ask it to label any state the learner reaches, including ones where the
learner dropped the cube. :class:`DistilledFetchExpert` is the paper's kind of expert (section
3.4.2: "a neural network that has access to the vectorized state"): a small MLP regressed on the
controller's labels over states from noisy expert rollouts.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from metadagger.errors import CheckpointError
from metadagger.tasks.fetch.env import UPSTREAM_ID, FetchState, lower_goal_to_object, read_fetch_state
from metadagger.utils.io import load_tensors, read_metadata, save_tensors
from metadagger.utils.optim import adam

#: Half the cube's side (metres): the grip site sits at the cube's centre when it is held.
CUBE_HALF = 0.025
OPEN, CLOSE = 1.0, -1.0
#: Finger opening (m) a little below fully open (0.1): narrower means the fingers are closing.
FINGERS_OPEN = 0.095
#: Finger openings (m) that mean "stopped by the cube" (its side is 0.05): below, the fingers
#: closed on nothing; above, they have not reached it yet.
HOLD_MIN, HOLD_MAX = 0.03, 0.065


@dataclass(frozen=True, kw_only=True)
class FetchExpert:
    """Scripted pick-and-place: go above the cube, open, descend, close, carry to the goal.

    Every call decides from the current state alone which phase applies: holding (cube between
    closed fingers at the grip site) carries it to the goal; otherwise the gripper re-approaches
    the cube, so a dropped or pushed cube is picked up again.

    Attributes:
        gain: Proportional gain from position error (m) to action (one unit moves 0.05 m).
        hover: Height above the cube's centre from which the gripper descends (m).
        align_tol: Horizontal grip-to-cube distance below which the gripper descends (m).
        grasp_tol: Vertical grip-to-cube distance below which the fingers close (m).
        carry_lift: Height above the goal at which the cube is carried until above it (m).
    """

    gain: float = 15.0
    hover: float = 0.05
    align_tol: float = 0.015
    grasp_tol: float = 0.015
    carry_lift: float = 0.03

    def __post_init__(self) -> None:
        for name, low, high in (
            ("gain", 0.5, 100.0),
            ("hover", 0.0, 0.3),
            ("align_tol", 1e-3, CUBE_HALF),
            ("grasp_tol", 1e-3, CUBE_HALF),
            ("carry_lift", 0.0, 0.3),
        ):
            value = getattr(self, name)
            if not low <= value <= high:
                raise ValueError(f"FetchExpert.{name} must be in [{low}, {high}], got {value}")

    def __call__(self, env: gym.Env) -> np.ndarray:
        """The full action (dx, dy, dz, fingers) for the current state of a Fetch env."""
        return self.act(read_fetch_state(env))

    def act(self, state: FetchState) -> np.ndarray:
        """The full action for ``state``: float32, shape (4,), within [-1, 1]."""
        grip, cube, goal = state.grip_pos, state.object_pos, state.goal
        to_cube = cube - grip
        if self._holding(state):
            target = goal.copy()
            if np.linalg.norm(goal[:2] - cube[:2]) > 2 * self.align_tol:
                target[2] = max(goal[2], cube[2]) + self.carry_lift
            return self._move(target - cube, CLOSE)
        off = float(np.linalg.norm(to_cube[:2]))
        at_cube = off < self.align_tol and abs(to_cube[2]) < self.grasp_tol
        # Once the fingers have started to close round the cube, finish the grasp; fingers
        # that closed on nothing fall through to the funnel below, which opens them.
        closing = HOLD_MIN < state.gripper_opening < FINGERS_OPEN and _near(to_cube)
        if (at_cube and state.gripper_opening > HOLD_MIN) or closing:
            return self._move(to_cube, CLOSE)
        # A funnel over the cube: the further off to the side, the higher the gripper should be,
        # so noise pushes it back up the funnel instead of into a phase that no longer applies.
        height = min(self.hover, max(0.0, 2.0 * (off - self.align_tol)))
        delta = to_cube + np.array([0.0, 0.0, height])
        if delta[2] > self.grasp_tol and off > CUBE_HALF:
            # Below the funnel and beside the cube: rise before moving over, or the open
            # fingers would sweep the cube away.
            delta[:2] = 0.0
        return self._move(delta, OPEN)

    def _holding(self, state: FetchState) -> bool:
        return _near(state.object_pos - state.grip_pos) and HOLD_MIN < state.gripper_opening < HOLD_MAX

    def _move(self, delta: np.ndarray, fingers: float) -> np.ndarray:
        xyz = np.clip(self.gain * delta, -1.0, 1.0)
        return np.append(xyz, fingers).astype(np.float32)


def _near(to_cube: np.ndarray) -> bool:
    """Whether the grip site is within the cube's half side of its centre, per axis group."""
    return bool(np.linalg.norm(to_cube[:2]) < CUBE_HALF and abs(to_cube[2]) < CUBE_HALF)


#: Positions differ by about 0.1 m: scaled by 10 the network's inputs are about 1.
FEATURE_SCALE = 10.0
N_FEATURES = 7


def state_features(state: FetchState) -> np.ndarray:
    """The distilled expert's input: cube minus grip, goal minus cube, finger opening (scaled)."""
    raw = np.concatenate([state.object_pos - state.grip_pos, state.goal - state.object_pos, [state.gripper_opening]])
    return (raw * FEATURE_SCALE).astype(np.float32)


@dataclass(frozen=True, kw_only=True)
class DistillConfig:
    """How :func:`distill_fetch_expert` collects data and fits the network.

    Attributes:
        seeds: Episode seeds of the controller's rollouts (keep them apart from evaluation seeds).
        noise: Largest s.d. of the Gaussian noise added to the executed x, y, z action; each
            episode draws its own s.d. uniformly in [0, noise], so the data covers the expert's
            own path and the states a clumsy learner reaches (labels stay noise-free).
        hidden: Width of the two hidden layers.
        epochs: Passes over the data.
        batch_size: Minibatch size.
        lr: Adam learning rate.
        seed: Seeds the noise, the initial weights and the minibatch order.
    """

    seeds: tuple[int, ...] = tuple(range(1000, 1200))
    noise: float = 0.3
    hidden: int = 128
    epochs: int = 60
    batch_size: int = 256
    lr: float = 1e-3
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))
        if not self.seeds:
            raise ValueError("DistillConfig.seeds must hold at least one seed, got none")
        for name, low, high in (("noise", 0.0, 1.0), ("lr", 1e-6, 1.0)):
            value = getattr(self, name)
            if not low <= value <= high:
                raise ValueError(f"DistillConfig.{name} must be in [{low}, {high}], got {value}")
        for name in ("hidden", "epochs", "batch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"DistillConfig.{name} must be a positive integer, got {getattr(self, name)}")


class DistilledFetchExpert:
    """A state-based network expert (the paper's kind) regressed on :class:`FetchExpert`'s labels.

    Args:
        hidden: Width of the two hidden layers of the MLP (7 inputs, 4 outputs).
    """

    def __init__(self, *, hidden: int = 128):
        if hidden < 1:
            raise ValueError(f"hidden must be a positive integer, got {hidden}")
        self.hidden = int(hidden)
        self.net = nn.Sequential(
            nn.Linear(N_FEATURES, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 4)
        )

    def __call__(self, env: gym.Env) -> np.ndarray:
        """The full action for the current state of a Fetch env."""
        return self.act(read_fetch_state(env))

    def act(self, state: FetchState) -> np.ndarray:
        """The full action for ``state``; the finger command is the sign of the regressed output."""
        with torch.no_grad():
            out = self.net(torch.from_numpy(state_features(state))[None])[0].numpy()
        action = np.clip(out, -1.0, 1.0)
        action[3] = OPEN if out[3] >= 0 else CLOSE
        return action.astype(np.float32)

    def save(self, path: str | Path) -> Path:
        """Write the weights as safetensors; the width goes in the header metadata."""
        metadata = {"kind": type(self).__name__, "hidden": str(self.hidden), "features": str(N_FEATURES)}
        return save_tensors(path, dict(self.net.state_dict()), metadata=metadata)

    @classmethod
    def load(cls, path: str | Path) -> DistilledFetchExpert:
        """Rebuild a saved expert; a file that is not one raises :class:`CheckpointError`."""
        metadata = read_metadata(path, called="distilled Fetch expert")
        if metadata.get("kind") != cls.__name__ or metadata.get("features") != str(N_FEATURES):
            raise CheckpointError(
                f"{path} is not a distilled Fetch expert (metadata {metadata}); pass a file written by "
                "DistilledFetchExpert.save"
            )
        expert = cls(hidden=int(metadata["hidden"]))
        expert.net.load_state_dict(load_tensors(path, called="distilled Fetch expert"))
        return expert


def collect_distillation_data(
    config: DistillConfig, controller: FetchExpert | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Features and controller labels of every state of noisy controller rollouts (50 steps each).

    Rollouts run on upstream's state-based env (no rendering) with the goal at the cube's height.
    """
    controller = FetchExpert() if controller is None else controller
    rng = np.random.default_rng(config.seed)
    fetch = gym.make(UPSTREAM_ID).unwrapped
    features, labels = [], []
    try:
        for seed in config.seeds:
            fetch.reset(seed=seed)
            lower_goal_to_object(fetch)
            sd = rng.uniform(0.0, config.noise)
            for _ in range(50):
                state = read_fetch_state(fetch)
                label = controller.act(state)
                features.append(state_features(state))
                labels.append(label)
                executed = label.copy()
                executed[:3] = np.clip(executed[:3] + rng.normal(0.0, sd, 3), -1.0, 1.0)
                fetch.step(executed)
    finally:
        fetch.close()
    return np.stack(features), np.stack(labels).astype(np.float32)


def distill_fetch_expert(config: DistillConfig) -> DistilledFetchExpert:
    """Fit a :class:`DistilledFetchExpert` by MSE regression on :func:`collect_distillation_data`."""
    features, labels = collect_distillation_data(config)
    generator = torch.Generator().manual_seed(config.seed)
    with torch.random.fork_rng():  # seeds the initial weights without touching global state
        torch.manual_seed(config.seed)
        expert = DistilledFetchExpert(hidden=config.hidden)
    x, y = torch.from_numpy(features), torch.from_numpy(labels)
    optimiser = adam(expert.net.parameters(), lr=config.lr)
    for _ in range(config.epochs):
        for batch in torch.randperm(len(x), generator=generator).split(config.batch_size):
            loss = nn.functional.mse_loss(expert.net(x[batch]), y[batch])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
    return expert
