"""Lockstep lanes: many episodes stepped together, one trunk forward per step for all of them.

A *lane* is one episode being stepped, in an env of its own. :class:`Lanes` holds ``width`` of
them: every step it stacks the live lanes' observations into one batch of exactly ``width`` rows
(the idle rows zero), runs pi*'s trunk on it once, applies each lane's own head to its row, and
steps each lane's env. At a fixed batch shape a row's output does not depend on the other rows
(tests/imitation/test_lanes.py checks it), so an episode is the same whichever episodes share its
steps, and whichever lane it runs in; it depends on the width, which the config fixes. When few
lanes are live the batch is cut to a smaller shape, but only to one checked, when the lanes are
made, to give every row the width's very bits (:data:`SHAPE_STEP`): the numbers stay the width's.

The trunk features computed to act are kept with the trajectory (:attr:`Trajectory.features`),
so the fits, gates and contexts that read the episode later need no second trunk pass.

:func:`run_chains` runs many *chains* -- plain sequential functions that roll episodes out and
refit heads one after another (a seed's DAgger rounds under one gate, say) -- with their episodes
in lanes: each chain runs in a thread of its own, one at a time, until it asks for an episode or
a head-only fit; the episodes asked for wait for a free lane in the order they were asked, and
the fits asked for run together, as one batched problem
(:func:`~metadagger.imitation.head_fits.fit_heads`), whenever the lanes have room that no
episode is waiting for. A chain resumes when what it asked for is done. The method's code stays
the sequential code it is (:mod:`metadagger.metal_dagger.method`).
"""

from __future__ import annotations

import copy
import threading
from collections import deque
from dataclasses import dataclass, replace
from typing import Any, Callable, Generic, Protocol, Sequence, TypeVar

import numpy as np
import torch
import torch.nn.functional as F

from metadagger.errors import UserError
from metadagger.imitation.early_stop import CosineEarlyStop
from metadagger.imitation.head_fits import FittedHead, HeadFit, fit_heads
from metadagger.imitation.rollouts import ActionNoise, EpisodeRecorder, Trajectory
from metadagger.policies import PolicyNet
from metadagger.tasks.base import Task
from metadagger.utils.device import compute_device

T = TypeVar("T")

#: The most lanes a config may ask for.
MAX_LANES = 256

#: A step's trunk forward runs on the live lanes' rows alone, padded to a multiple of this many
#: rows where that shape gives the width's bits (:meth:`Lanes._exact_shapes`), else to the width.
#: The pinned kernels compute a batch's rows in blocks of 4, so no other shape can keep them.
SHAPE_STEP = 4

#: Bumped by every change to what a laned run (lanes above 1) computes: stamped beside the width
#: (:func:`lanes_stamp`), so that laned artifacts made before the change are stale.
LANE_NUMERICS = 2


def lanes_stamp(width: int) -> dict[str, int]:
    """The lanes' part of a stage's stamp: nothing for width 1 (every episode alone, as before
    lanes existed), else the width and :data:`LANE_NUMERICS`."""
    return {} if width == 1 else {"lanes": width, "lane_numerics": LANE_NUMERICS}


def check_lanes(name: str, value: Any) -> None:
    """Raise a :class:`~metadagger.errors.UserError` naming config field ``name`` unless ``value`` is
    a lane width: an integer from 1 to :data:`MAX_LANES`."""
    if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= MAX_LANES:
        raise UserError(f"{name} must be an integer from 1 to {MAX_LANES}, got {value!r}; e.g. 32")


# the chain that runs in this thread (run_chains sets it)
_running = threading.local()


def current_lane() -> Lane | None:
    """The :class:`Lane` of the chain running in this thread, or None outside :func:`run_chains`'s
    chains: a learner made inside a chain rolls its episodes out and fits its heads through it."""
    return getattr(_running, "lane", None)


@dataclass(frozen=True)
class EpisodeRequest:
    """One episode to roll out in a lane."""

    seed: int
    """The env's reset seed."""
    head: np.ndarray | None
    """The learner's head as a flat float32 vector (``Policy.head_vector``); None: the expert
    drives (a demonstration)."""
    early_stop: float | None = None
    """Threshold of the cosine early stop (:class:`~metadagger.imitation.early_stop.CosineEarlyStop`);
    None: none."""
    max_steps: int | None = None
    """Step cap (not a success); None: the env's own end."""
    keep_images: bool = False
    """Keep the acted-on images in the trajectory; by default only their features are kept (the
    trajectory's ``obs`` is a stand-in, :func:`~metadagger.imitation.data.unkept_images`)."""
    noise: ActionNoise | None = None
    """Where the expert drives: how its executed action is perturbed (DART); None: not at all."""


class _FeatureRows:
    """The trunk features an episode acted on, one row a step, in one float32 buffer that doubles
    when full. One buffer, not a tensor a step: thousands of small allocations that outlive each
    step's large transient ones would keep the process's heap from shrinking."""

    def __init__(self, feature_dim: int) -> None:
        self._rows = np.empty((256, feature_dim), dtype=np.float32)
        self._count = 0

    def append(self, row: torch.Tensor) -> None:
        """Add one step's features (a 1-D tensor of ``feature_dim`` floats), copied."""
        if self._count == len(self._rows):
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        self._rows[self._count] = row.numpy()
        self._count += 1

    def array(self) -> np.ndarray:
        """Every row so far, (steps, feature_dim), in a new array of its own."""
        return self._rows[: self._count].copy()


class _Lane:
    """One live episode: its recorder, its head's weight and bias, the features it acted on."""

    def __init__(self, env: Any, request: EpisodeRequest, out_dim: int, feature_dim: int) -> None:
        self.request = request
        stop = None if request.early_stop is None else CosineEarlyStop(threshold=request.early_stop)
        self.episode = EpisodeRecorder(
            env,
            seed=request.seed,
            max_steps=request.max_steps,
            early_stop=stop,
            keep_images=request.keep_images,
            noise=request.noise,
        )
        self.weight: torch.Tensor | None = None
        self.bias: torch.Tensor | None = None
        if request.head is not None:
            head = torch.from_numpy(np.ascontiguousarray(request.head, dtype=np.float32))
            n_weight = head.numel() - out_dim
            self.weight, self.bias = head[:n_weight].view(out_dim, -1), head[n_weight:]
        self.features = _FeatureRows(feature_dim)


class Lanes:
    """``width`` lanes of ``task``'s learner env, acting through ``net``'s trunk.

    The trunk runs on the process's compute device (:func:`~metadagger.utils.device.compute_device`:
    on a GPU, a copy of it); the features come back to the CPU, where the heads act.

    Args:
        task: the task whose learner envs the lanes step.
        net: the network whose trunk computes every lane's features (pi*'s); its head is not used.
        width: the lanes, and the batch shape of every trunk forward.
    """

    def __init__(self, task: Task, net: PolicyNet, *, width: int) -> None:
        if not isinstance(width, int) or width < 1:
            raise ValueError(f"lanes need a width >= 1, got {width!r}")
        self.net, self.width = net, width
        self._device = compute_device()
        self._trunk = net.trunk if self._device.type == "cpu" else copy.deepcopy(net.trunk).to(self._device)
        self.discrete = net.discrete
        self.out_dim = int(net.arch["n_outputs"])
        self._task = task
        self._envs: list[Any] = [None] * width  # made when a lane is first used: an env is MBs (CarRacing: about 8)
        self._lanes: list[_Lane | None] = [None] * width
        self._batch = np.zeros((width, *net.arch["obs_shape"]), dtype=np.uint8)
        #: trunk forwards so far (one per step of the live lanes)
        self.forwards = 0
        #: the batch shapes a step's trunk forward may take, smallest first (:meth:`_exact_shapes`)
        self.shapes = self._exact_shapes()

    def _features(self, images: np.ndarray) -> torch.Tensor:
        """pi*'s trunk on a batch of images, on the compute device; the features on the CPU."""
        return self._trunk(self.net.preprocess(torch.from_numpy(images).to(self._device))).cpu()

    def _exact_shapes(self) -> list[int]:
        """The batch shapes, below the width, at which the trunk gives each row the very bits it gives
        it in a batch of ``width`` rows, then the width. Checked once, on a probe batch of random
        images and on the same batch reversed: a shape is kept when its rows, in either order, are
        the width's rows. None is kept unless the width's own rows keep their bits when reversed (a
        kernel that computes a tail of the batch otherwise gives a row in the tail other bits, and
        then an episode's bits depend on its lane, so its lane must stay its row)."""
        candidates = range(SHAPE_STEP, self.width, SHAPE_STEP)
        if not candidates:
            return [self.width]
        probe = np.random.default_rng(0).integers(0, 256, size=self._batch.shape, dtype=np.uint8)
        with torch.inference_mode():
            full = self._features(probe)
            if not torch.equal(self._features(probe[::-1].copy()), full.flip(0)):
                return [self.width]
            exact = [
                s
                for s in candidates
                if torch.equal(self._features(probe[:s]), full[:s])
                and torch.equal(self._features(probe[:s][::-1].copy()), full[:s].flip(0))
            ]
        return [*exact, self.width]

    def free(self) -> list[int]:
        """The idle lanes, in order."""
        return [i for i, lane in enumerate(self._lanes) if lane is None]

    def busy(self) -> bool:
        """Whether any lane is live."""
        return any(lane is not None for lane in self._lanes)

    def start(self, index: int, request: EpisodeRequest) -> None:
        """Start ``request``'s episode in idle lane ``index``."""
        if self._lanes[index] is not None:
            raise RuntimeError(f"lane {index} is still live")
        if self._envs[index] is None:
            self._envs[index] = self._task.make_env()
        self._lanes[index] = _Lane(self._envs[index], request, self.out_dim, self.net.feature_dim)

    def step(self) -> list[tuple[int, Trajectory]]:
        """One step of every live lane; returns the episodes that ended, ``(lane, trajectory)``, by lane."""
        live = [i for i, lane in enumerate(self._lanes) if lane is not None]
        if not live:
            return []
        # the live lanes' images in the smallest exact shape that holds them: each lane in its own row
        # at the width (its bits may depend on its row), else in the first rows
        shape = next(shape for shape in self.shapes if shape >= len(live))
        rows = live if shape == self.width else list(range(len(live)))
        batch = self._batch[:shape]
        batch[:] = 0
        for row, i in zip(rows, live):
            batch[row] = self._lanes[i].episode.obs
        with torch.inference_mode():
            features = self._features(batch)
            self.forwards += 1
            actions = {i: self._act(self._lanes[i], features[row : row + 1]) for row, i in zip(rows, live)}
        ended = []
        for row, i in zip(rows, live):
            lane = self._lanes[i]
            lane.features.append(features[row])
            if lane.episode.step(actions[i]):
                trajectory = lane.episode.trajectory()
                ended.append((i, replace(trajectory, features=lane.features.array())))
                self._lanes[i] = None
        return ended

    def _act(self, lane: _Lane, features: torch.Tensor) -> Any:
        """The lane's action on its row of features: the expert's (perturbed where the episode has
        noise), or its head's output."""
        if lane.weight is None:
            return lane.episode.expert_action()
        # nn.Linear's own kernel, on one row: a lane of width 1 acts exactly as Policy does
        out = F.linear(features, lane.weight, lane.bias)
        if self.discrete:
            return int(out.argmax(dim=1)[0])
        return out[0].numpy().astype(np.float32, copy=True)

    def run(self, requests: Sequence[EpisodeRequest], *, each: Callable[[Trajectory], Any] | None = None) -> list[Any]:
        """Every episode of ``requests``, in lanes, each one started in the first free lane in
        request order; the trajectories (or ``each`` of each, applied as it ends) in request order."""
        queue = deque(enumerate(requests))
        out: list[Any] = [None] * len(requests)
        owner: dict[int, int] = {}
        while queue or self.busy():
            for lane in self.free():
                if not queue:
                    break
                owner[lane], request = queue.popleft()
                self.start(lane, request)
            for lane, trajectory in self.step():
                out[owner.pop(lane)] = trajectory if each is None else each(trajectory)
        return out

    def close(self) -> None:
        """Close every lane's env."""
        for env in self._envs:
            if env is not None:
                env.close()

    def __enter__(self) -> Lanes:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class _Aborted(BaseException):
    """Raised in a chain whose run is abandoned because another chain failed."""


class Lane(Protocol):
    """What a chain asks of the lanes (:func:`run_chains` hands each chain one)."""

    def roll(self, request: EpisodeRequest) -> Trajectory:
        """One episode, rolled out in a lane; returns when it has ended."""

    def fit(self, request: HeadFit) -> FittedHead:
        """One head-only fit, run batched with the other chains' fits; returns when it is done."""


class _Chain(Generic[T]):
    """A chain's thread, handed control by :func:`run_chains` and handing it back; the chain's :class:`Lane`."""

    def __init__(self, body: Callable[[Lane], T], handback: threading.Semaphore):
        self.body, self.handback = body, handback
        self.resume = threading.Semaphore(0)
        self.request: EpisodeRequest | HeadFit | None = None
        self.reply: Trajectory | FittedHead | None = None
        self.result: T | None = None
        self.error: BaseException | None = None
        self.done = False
        self.aborted = False
        self.thread = threading.Thread(target=self._run, daemon=True, name="metadagger-chain")

    def _run(self) -> None:
        self.resume.acquire()
        _running.lane = self
        try:
            if not self.aborted:
                self.result = self.body(self)
        except _Aborted:
            pass
        except BaseException as exc:  # handed to run_chains, which raises it in the caller
            self.error = exc
        self.done = True
        self.handback.release()

    def roll(self, request: EpisodeRequest) -> Trajectory:
        """Ask for one episode and wait, control handed back, until it has ended."""
        return self._ask(request)  # type: ignore[return-value]

    def fit(self, request: HeadFit) -> FittedHead:
        """Ask for one head-only fit and wait, control handed back, until the batched fits are done."""
        return self._ask(request)  # type: ignore[return-value]

    def _ask(self, request: EpisodeRequest | HeadFit) -> Trajectory | FittedHead:
        self.request = request
        self.handback.release()
        self.resume.acquire()
        if self.aborted:
            raise _Aborted
        reply, self.reply = self.reply, None
        assert reply is not None
        return reply


def run_chains(lanes: Lanes, bodies: Sequence[Callable[[Lane], T]]) -> list[T]:
    """Run each chain ``body(lane)`` to its end, its episodes in ``lanes``; their results in order.

    A chain is a function of one argument, a :class:`Lane`, whose ``roll`` it calls with an
    :class:`EpisodeRequest` to get that episode's trajectory and whose ``fit`` runs a head-only
    fit (:func:`current_lane` returns the same lane inside the chain). Chains run one at a time,
    each in its own thread, so their arithmetic is what it would be alone; a fit's head does not
    depend on the fits batched with it. A chain that raises stops the others, and the error is
    raised here.
    """
    handback = threading.Semaphore(0)
    chains = [_Chain(body, handback) for body in bodies]
    waiting: deque[_Chain[T]] = deque()
    fitting: list[_Chain[T]] = []
    owner: dict[int, _Chain[T]] = {}

    def advance(chain: _Chain[T]) -> None:
        # hand control to the chain until it asks for an episode or a fit, or ends
        chain.resume.release()
        handback.acquire()
        if chain.error is not None:
            _abort(chains)
            raise chain.error
        if not chain.done:
            (fitting if isinstance(chain.request, HeadFit) else waiting).append(chain)

    for chain in chains:
        chain.thread.start()
    try:
        for chain in chains:
            advance(chain)
        while waiting or fitting or lanes.busy():
            for lane in lanes.free():
                if not waiting:
                    break
                chain = waiting.popleft()
                owner[lane] = chain
                lanes.start(lane, chain.request)  # type: ignore[arg-type]
            if fitting and lanes.free():  # room in the lanes that no episode waits for: the fits hold it up
                asking, fitting = fitting, []
                fitted = fit_heads([chain.request for chain in asking], out_dim=lanes.out_dim, discrete=lanes.discrete)
                for chain, head in zip(asking, fitted):
                    chain.reply = head
                    advance(chain)
                continue
            for lane, trajectory in lanes.step():
                chain = owner.pop(lane)
                chain.reply = trajectory
                advance(chain)
    except BaseException:
        _abort(chains)
        raise
    return [chain.result for chain in chains]  # type: ignore[misc]


def _abort(chains: Sequence[_Chain[Any]]) -> None:
    """End every chain still waiting: each raises :class:`_Aborted` where it waits and finishes."""
    for chain in chains:
        if not chain.done:
            chain.aborted = True
            chain.resume.release()
    for chain in chains:
        chain.thread.join(timeout=10)
