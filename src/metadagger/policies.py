"""The policy network (paper Fig. 7) and the :class:`Policy` that acts in an env.

The network splits into a ``trunk`` (layers 1..n-1: convolutions, flatten, every fully-connected
layer but the last) and a ``head`` (layer n, one ``nn.Linear``). MetaL DAgger treats the head as
data: :meth:`Policy.head_vector` flattens it to one float32 vector, the unit a mapper works on.
Checkpoints are safetensors files whose metadata holds the constructor arguments, so
:func:`load_policy` rebuilds the network without pickle.
"""

from __future__ import annotations

import contextlib
import copy
import inspect
import json
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np
import torch
from torch import nn
from torch.nn.utils import parameters_to_vector, vector_to_parameters

from metadagger.errors import CheckpointError, UserError
from metadagger.tasks.base import Task
from metadagger.utils.io import load_tensors, read_metadata, save_tensors
from metadagger.version import __version__, source_revision

#: Defaults sized for 96x96x3 -> 20 classes: about 150K parameters (paper Sec. 3.2).
DEFAULT_CONV_CHANNELS = (8, 16, 32, 32)
DEFAULT_KERNEL_SIZES = (5, 5, 3, 3)
DEFAULT_HIDDEN = (112, 64)
_FORMAT = "metadagger.policy/1"


def _conv_out(size: int, kernel: int, stride: int) -> int:
    # "same" padding k // 2
    return (size + 2 * (kernel // 2) - kernel) // stride + 1


def _positive_ints(field: str, value: Any, *, min_len: int) -> tuple[int, ...]:
    values = tuple(value)
    if len(values) < min_len or not all(isinstance(v, int) and v > 0 for v in values):
        raise UserError(
            f"{field} must be at least {min_len} positive integers, got {value!r}; pass e.g. {field}=(8, 16)"
        )
    return values


class SpatialSoftmax(nn.Module):
    """Each channel's softmax over the image, reduced to its expected (x, y) in [-1, 1].

    (N, C, H, W) feature maps -> (N, 2C) keypoint coordinates (x of every channel, then y), as in
    Levine et al., "End-to-end training of deep visuomotor policies" (2016). Positions become
    features that a linear layer can compare, which generalises across object layouts far better
    than flattened maps when only a few dozen layouts are seen.
    """

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        n, c, h, w = maps.shape
        probs = torch.softmax(maps.flatten(2), dim=-1).view(n, c, h, w)
        xs = torch.linspace(-1.0, 1.0, w, device=maps.device)
        ys = torch.linspace(-1.0, 1.0, h, device=maps.device)
        return torch.cat([(probs.sum(2) * xs).sum(-1), (probs.sum(3) * ys).sum(-1)], dim=1)


class PolicyNet(nn.Module):
    """CNN trunk + linear head mapping a batch of uint8 HWC images to logits or a vector.

    Every convolution has padding ``kernel // 2`` and is followed by ReLU; the convolutions' maps
    are flattened (or reduced to keypoints by :class:`SpatialSoftmax`); the fully-connected layers
    of ``hidden`` each have ReLU; the head is one linear layer.

    Args:
        obs_shape: observation shape (H, W, C).
        n_outputs: classes (discrete) or vector length (continuous).
        discrete: whether outputs are class logits (cross-entropy) or a vector (MSE).
        conv_channels: output channels of each convolution.
        kernel_sizes: kernel width of each convolution (same length as ``conv_channels``).
        hidden: widths of the fully-connected layers before the head.
        strides: stride of each convolution (default 2 for all).
        spatial_softmax: reduce the last maps to keypoint coordinates instead of flattening them.
    """

    def __init__(
        self,
        *,
        obs_shape: tuple[int, int, int],
        n_outputs: int,
        discrete: bool,
        conv_channels: tuple[int, ...] = DEFAULT_CONV_CHANNELS,
        kernel_sizes: tuple[int, ...] = DEFAULT_KERNEL_SIZES,
        hidden: tuple[int, ...] = DEFAULT_HIDDEN,
        strides: tuple[int, ...] | None = None,
        spatial_softmax: bool = False,
    ):
        super().__init__()
        if len(tuple(obs_shape)) != 3:
            raise UserError(f"obs_shape must be (H, W, C), got {obs_shape!r}; pass the env's observation_space.shape")
        obs_shape = _positive_ints("obs_shape", obs_shape, min_len=3)
        conv_channels = _positive_ints("conv_channels", conv_channels, min_len=1)
        kernel_sizes = _positive_ints("kernel_sizes", kernel_sizes, min_len=1)
        # an empty ``hidden`` is allowed: the head then reads the flattened convolutions
        hidden = _positive_ints("hidden", hidden, min_len=0)
        strides = (2,) * len(conv_channels) if strides is None else _positive_ints("strides", strides, min_len=1)
        if len(strides) != len(conv_channels):
            raise UserError(
                f"strides has {len(strides)} entries but conv_channels has {len(conv_channels)}; give one stride per "
                "convolution"
            )
        if len(kernel_sizes) != len(conv_channels):
            raise UserError(
                f"kernel_sizes has {len(kernel_sizes)} entries but conv_channels has {len(conv_channels)}; give one "
                "kernel per convolution"
            )
        if not isinstance(n_outputs, int) or n_outputs <= 0:
            raise UserError(f"n_outputs must be a positive integer, got {n_outputs!r}")
        self.arch: dict[str, Any] = {
            "obs_shape": list(obs_shape),
            "n_outputs": n_outputs,
            "discrete": bool(discrete),
            "conv_channels": list(conv_channels),
            "kernel_sizes": list(kernel_sizes),
            "hidden": list(hidden),
            "strides": list(strides),
            "spatial_softmax": bool(spatial_softmax),
        }
        height, width, channels = obs_shape
        # in-place ReLUs: the same values and gradients (autograd's ReLU backward reads the output
        # either way), one allocation fewer per layer
        layers: list[nn.Module] = []
        for out_channels, kernel, stride in zip(conv_channels, kernel_sizes, strides):
            layers += [
                nn.Conv2d(channels, out_channels, kernel, stride=stride, padding=kernel // 2),
                nn.ReLU(inplace=True),
            ]
            channels, height, width = out_channels, _conv_out(height, kernel, stride), _conv_out(width, kernel, stride)
        if spatial_softmax:
            layers.append(SpatialSoftmax())
            width_in = 2 * channels
        else:
            layers.append(nn.Flatten())
            width_in = channels * height * width
        for width_out in hidden:
            layers += [nn.Linear(width_in, width_out), nn.ReLU(inplace=True)]
            width_in = width_out
        self.trunk = nn.Sequential(*layers)
        self.head = nn.Linear(width_in, n_outputs)
        self.feature_dim = width_in

    @property
    def discrete(self) -> bool:
        """Whether the outputs are class logits."""
        return bool(self.arch["discrete"])

    @staticmethod
    def preprocess(obs: torch.Tensor) -> torch.Tensor:
        """uint8 (N, H, W, C) images -> float (N, C, H, W) in [0, 1]; the only place this happens."""
        return obs.permute(0, 3, 1, 2).float().div_(255.0)

    def features(self, obs: torch.Tensor) -> torch.Tensor:
        """Trunk output (N, feature_dim) for uint8 (N, H, W, C) images."""
        return self.trunk(self.preprocess(obs))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Head output (N, n_outputs) for uint8 (N, H, W, C) images."""
        return self.head(self.features(obs))

    def act_outputs(self, obs: torch.Tensor) -> torch.Tensor:
        """:meth:`forward` without ``nn.Module``'s call machinery, so forward hooks do not run:
        acting on one image at a time, that machinery costs a sixth of the step. The same numbers
        as :meth:`forward`; :class:`Policy` acts through it."""
        hidden = self.preprocess(obs)
        for layer in self.trunk:
            hidden = layer.forward(hidden)
        return self.head.forward(hidden)

    def init_weights(self, seed: int, *, head_only: bool = False) -> None:
        """Xavier-uniform weights and zero biases (paper Tables 8-9), deterministic from ``seed``."""
        generator = torch.Generator().manual_seed(int(seed))
        modules = [self.head] if head_only else [m for m in self.modules() if isinstance(m, (nn.Conv2d, nn.Linear))]
        with torch.no_grad():
            for module in modules:
                nn.init.xavier_uniform_(module.weight, generator=generator)
                nn.init.zeros_(module.bias)


class Policy:
    """A :class:`PolicyNet` that acts on raw env observations, plus the name of its task.

    Args:
        net: the network (its constructor arguments are kept in ``net.arch``).
        task: name of the task it was built for (``metadagger.make_task(task)``).
    """

    def __init__(self, *, net: PolicyNet, task: str):
        self.net = net.eval()
        self.task = task
        self._obs_shape = tuple(net.arch["obs_shape"])

    @property
    def arch(self) -> dict[str, Any]:
        """The network's constructor arguments."""
        return dict(self.net.arch)

    @property
    def discrete(self) -> bool:
        """Whether actions are class indices (else float32 vectors)."""
        return self.net.discrete

    @property
    def head_size(self) -> int:
        """Length of :meth:`head_vector`: out * in + out."""
        return self.net.head.weight.numel() + self.net.head.bias.numel()

    def _check_obs(self, obs: np.ndarray) -> None:
        if not isinstance(obs, np.ndarray) or obs.dtype != np.uint8 or obs.shape[1:] != self._obs_shape:
            got = f"{type(obs).__name__} {getattr(obs, 'dtype', '')} {getattr(obs, 'shape', '')}"
            raise UserError(
                f"observations must be uint8 arrays of shape (N, {', '.join(map(str, self._obs_shape))}), got {got}; "
                "pass raw env observations of the task this policy was built for"
            )

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        """Actions for a batch of raw observations (N, H, W, C) uint8: int64 classes or float32 (N, d)."""
        self._check_obs(obs)
        with torch.inference_mode():
            out = self.net.act_outputs(torch.from_numpy(obs))
        if self.discrete:
            return out.argmax(dim=1).numpy()
        return out.numpy().astype(np.float32, copy=False)

    def __call__(self, obs: np.ndarray) -> int | np.ndarray:
        """The learner action for one raw observation (H, W, C) uint8: an int, or a float32 vector."""
        if isinstance(obs, np.ndarray) and obs.ndim == 4:
            raise UserError(
                f"policy(obs) takes one observation (H, W, C), got a batch of shape {obs.shape}; "
                "use policy.act_batch(obs) for a batch"
            )
        with _one_torch_thread():
            action = self.act_batch(obs[None] if isinstance(obs, np.ndarray) else obs)[0]
        return int(action) if self.discrete else action

    def head_vector(self) -> torch.Tensor:
        """Layer n's weight and bias as one flat float32 1-D tensor (a copy)."""
        return parameters_to_vector(self.net.head.parameters()).detach().clone()

    def load_head_vector(self, vector: torch.Tensor | np.ndarray) -> None:
        """Put a flat float32 vector from :meth:`head_vector` (or a mapper) back into layer n."""
        if isinstance(vector, np.ndarray):
            vector = torch.from_numpy(vector)
        expected = self.head_size
        out_dim, in_dim = self.net.head.weight.shape
        if (
            not isinstance(vector, torch.Tensor)
            or vector.dtype != torch.float32
            or vector.ndim != 1
            or vector.numel() != expected
        ):
            got = f"{getattr(vector, 'dtype', type(vector).__name__)} of shape {tuple(getattr(vector, 'shape', ()))}"
            raise UserError(
                f"head vector must be 1-D float32 of length {expected} = {out_dim}*{in_dim} + {out_dim}, got {got}; "
                "pass a vector from head_vector() of a policy with the same architecture"
            )
        with torch.no_grad():
            # vector_to_parameters makes each parameter a view of its input: copy, so training
            # the head never writes into the caller's array
            vector_to_parameters(vector.to(self.net.head.weight.device).clone(), self.net.head.parameters())

    def reset_head(self, seed: int) -> None:
        """Re-initialise layer n: Xavier-uniform weight, zero bias, deterministic from ``seed``."""
        self.net.init_weights(seed, head_only=True)

    def freeze_trunk(self) -> None:
        """Stop gradients into layers 1..n-1 (only the head trains afterwards)."""
        self.net.trunk.requires_grad_(False)

    def copy(self) -> Policy:
        """An independent deep copy."""
        return Policy(net=copy.deepcopy(self.net), task=self.task)

    def with_own_head(self) -> Policy:
        """A policy whose trunk is this one's (the same module) and whose head is a copy of this one's."""
        return Policy(net=copy.deepcopy(self.net, memo={id(self.net.trunk): self.net.trunk}), task=self.task)

    def save(self, path: str | Path) -> Path:
        """Write the weights and constructor arguments to a safetensors file (atomically)."""
        metadata = {
            "format": _FORMAT,
            "arch": json.dumps(self.net.arch, sort_keys=True),
            "task": self.task,
            "version": __version__,
            "git_revision": source_revision(),
        }
        return save_tensors(path, self.net.state_dict(), metadata=metadata)


@contextlib.contextmanager
def _one_torch_thread() -> Iterator[None]:
    """Run the block with one torch thread, then restore the caller's thread count."""
    # One observation is too little work to split: measured on a busy 2-core machine, policy(obs)
    # took 80 ms with torch's default 2 threads and 0.8 ms with one.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def load_policy(path: str | Path) -> Policy:
    """Rebuild a policy saved by :meth:`Policy.save` (no pickle).

    Raises:
        CheckpointError: the file is missing, corrupt, or its metadata/tensors do not rebuild.
    """
    metadata = read_metadata(path, called="policy checkpoint")
    tensors = load_tensors(path, called="policy checkpoint")
    if metadata.get("format") != _FORMAT:
        raise CheckpointError(
            f"{path} is not a metadagger policy (format {metadata.get('format')!r}, expected {_FORMAT!r}); pass a "
            "file written by Policy.save"
        )
    try:
        net = PolicyNet(**json.loads(metadata["arch"]))
    except (KeyError, TypeError, ValueError) as exc:
        message = str(exc).splitlines()[0]
        raise CheckpointError(
            f"policy checkpoint {path} does not rebuild ({type(exc).__name__}: {message}); re-save it with this "
            "metadagger version"
        ) from None
    mismatch = tensor_mismatch(tensors, net.state_dict())
    if mismatch:
        raise CheckpointError(
            f"policy checkpoint {path} does not fit the architecture its metadata records ({mismatch}); restore the "
            "file, or "
            "delete it and re-run the command that wrote it (for a run's pi*: metadagger pistar --out RUN)"
        )
    net.load_state_dict(tensors, strict=True)
    return Policy(net=net, task=metadata.get("task", ""))


def tensor_mismatch(found: Mapping[str, torch.Tensor], expected: Mapping[str, torch.Tensor]) -> str:
    """How the tensors ``found`` in a checkpoint differ from the ``expected`` ones (a module's
    ``state_dict()``) in names and shapes, as one line; "" when they fit."""
    missing = [name for name in expected if name not in found]
    unexpected = [name for name in found if name not in expected]
    shapes = [
        f"{name} has shape {tuple(found[name].shape)}, expected {tuple(tensor.shape)}"
        for name, tensor in expected.items()
        if name in found and found[name].shape != tensor.shape
    ]
    parts = [
        f"{what}{_first_few(names)}"
        for what, names in (("missing tensor(s) ", missing), ("unexpected tensor(s) ", unexpected), ("", shapes))
        if names
    ]
    return "; ".join(parts)


def _first_few(items: list[str], limit: int = 3) -> str:
    """``items`` joined by commas, cut to the first ``limit`` and a count of the rest."""
    shown = ", ".join(items[:limit])
    return shown if len(items) <= limit else f"{shown} and {len(items) - limit} more"


def make_policy(task: Task, *, seed: int, **arch_overrides: Any) -> Policy:
    """A freshly initialised policy for ``task`` (Xavier weights, zero biases from ``seed``).

    The observation shape comes from the task's learner env, the outputs from
    ``task.label_dim()`` and the loss type from ``task.is_discrete``; the task's ``policy_arch``
    and then ``arch_overrides`` set any of ``conv_channels``, ``kernel_sizes``, ``hidden``,
    ``strides`` and ``spatial_softmax``.
    """
    arch_overrides = {**task.policy_arch, **arch_overrides}
    allowed = set(inspect.signature(PolicyNet).parameters) - {"obs_shape", "n_outputs", "discrete"}
    unknown = sorted(set(arch_overrides) - allowed)
    if unknown:
        raise UserError(f"unknown architecture option(s) {unknown}: expected some of {sorted(allowed)}")
    env = task.make_env()
    try:
        obs_shape = tuple(int(s) for s in env.observation_space.shape)
    finally:
        env.close()
    net = PolicyNet(obs_shape=obs_shape, n_outputs=task.label_dim(), discrete=task.is_discrete, **arch_overrides)
    net.init_weights(seed)
    return Policy(net=net, task=task.name)
