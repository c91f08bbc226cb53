"""Kernel fingerprints: where two machines stop computing the same bits.

:func:`fingerprint_kernels` runs, on fixed inputs made from integers (the same bits on every
machine), each kind of computation a run does, in the order pi*'s first BC step meets them: numpy
and OpenCV, then one training step of the CarRacing policy network op by op (convolutions on
oneDNN and on ATen's own path, the fully-connected layers, the loss, every gradient, Adam), then
the lanes' kernels (a padded trunk forward, batched head fits), the gates' scores, then a CarRacing episode's
frames. Each gives the sha256 of its output. Two machines' fingerprints, compared with
:func:`compare_fingerprints`, name the first computation whose bits differ: the kernel to pin, or
to report.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, Callable

import numpy as np

from metadagger.errors import UserError
from metadagger.utils.io import read_json
from metadagger.utils.kernels import kernel_stamp, machine_description
from metadagger.version import source_revision

#: Frames and labels of the fixed batch: pi*'s batch size, CarRacing's frame and classes.
_BATCH, _SIZE, _CLASSES = 64, 96, 20
#: Steps of the CarRacing episode whose frames are fingerprinted.
_EPISODE_STEPS = 200


def _integers(n: int, salt: int) -> np.ndarray:
    """``n`` well-mixed uint32 values from integer arithmetic alone (the same on any machine)."""
    x = (np.arange(n, dtype=np.uint64) + np.uint64(salt)) * np.uint64(0x9E3779B97F4A7C15)
    x ^= x >> np.uint64(29)
    x *= np.uint64(0xBF58476D1CE4E5B9)
    return (x >> np.uint64(32)).astype(np.uint32)


def _uniform(shape: tuple[int, ...], salt: int) -> np.ndarray:
    """Float32 values in [-0.5, 0.5), exact (a uint32 scaled by a power of two)."""
    return (_integers(int(np.prod(shape)), salt).astype(np.float64) / 2.0**32 - 0.5).astype(np.float32).reshape(shape)


def _digest(name: str, value: Any) -> dict[str, Any]:
    """sha256 of an array's (or tensor's, or list of them) bytes, and its float64 sum for scale."""
    parts = value if isinstance(value, (list, tuple)) else [value]
    arrays = [np.ascontiguousarray(p.detach().numpy() if hasattr(p, "detach") else np.asarray(p)) for p in parts]
    sha = hashlib.sha256()
    for array in arrays:
        sha.update(array.tobytes())
    return {"op": name, "sha256": sha.hexdigest(), "sum": float(sum(a.astype(np.float64).sum() for a in arrays))}


def _numpy_and_opencv(ops: dict[str, Callable[[], Any]]) -> None:
    import cv2

    a, b = _uniform((256, 256), 1).astype(np.float64), _uniform((256, 256), 2).astype(np.float64)
    image = (_integers(192 * 192 * 3, 3) & 255).astype(np.uint8).reshape(192, 192, 3)
    ops["numpy.matmul (OpenBLAS)"] = lambda: a @ b
    ops["numpy.exp (SIMD loops)"] = lambda: np.exp(_uniform((4096,), 4) * 8)
    ops["opencv.resize INTER_AREA"] = lambda: cv2.resize(image, (96, 96), interpolation=cv2.INTER_AREA)
    ops["opencv.warpAffine"] = lambda: cv2.warpAffine(image, np.array([[0.8, 0.6, 3.5], [-0.6, 0.8, 40.25]]), (96, 96))


def _policy_step(ops: dict[str, Callable[[], Any]]) -> None:
    """One BC step of the CarRacing network (cross-entropy, Adam at pi*'s rate), op by op."""
    import torch
    import torch.nn.functional as F

    from metadagger.policies import PolicyNet
    from metadagger.utils.optim import adam

    frames = torch.from_numpy(
        (_integers(_BATCH * _SIZE * _SIZE * 3, 5) & 255).astype(np.uint8).reshape(_BATCH, _SIZE, _SIZE, 3)
    )
    labels = torch.from_numpy((_integers(_BATCH, 6) % _CLASSES).astype(np.int64))
    net = PolicyNet(obs_shape=(_SIZE, _SIZE, 3), n_outputs=_CLASSES, discrete=True)
    net.init_weights(0)
    x = net.preprocess(frames)
    first = net.trunk[0]
    z, w = torch.from_numpy(_uniform((_BATCH, 512), 7)), torch.from_numpy(_uniform((_CLASSES, 512), 8))

    def conv(onednn: bool) -> torch.Tensor:
        before = torch.backends.mkldnn.enabled
        torch.backends.mkldnn.enabled = onednn
        try:
            return first(x)
        finally:
            torch.backends.mkldnn.enabled = before

    def conv_weight_grad() -> torch.Tensor:
        weight = first.weight.detach().clone().requires_grad_(True)
        F.conv2d(x, weight, first.bias, first.stride, first.padding).square().mean().backward()
        return weight.grad

    def step() -> dict[str, Any]:
        optimizer = adam(net.parameters(), lr=1e-3)
        logits = net(frames)
        loss = F.cross_entropy(logits, labels)
        loss.backward()
        optimizer.step()
        return {
            "logits": logits,
            "loss": loss,
            **{f"grad {name}": p.grad for name, p in net.named_parameters()},
            "weights after Adam": list(net.parameters()),
        }

    ops["torch.init (xavier_uniform_)"] = lambda: list(net.parameters())
    ops["torch.preprocess"] = lambda: x
    ops["torch.conv2d (oneDNN)"] = lambda: conv(True)
    ops["torch.conv2d (ATen, oneDNN off)"] = lambda: conv(False)
    ops["torch.conv2d weight gradient"] = conv_weight_grad
    ops["torch.linear (MKL sgemm)"] = lambda: F.linear(z, w)
    ops["torch.log_softmax"] = lambda: F.log_softmax(F.linear(z, w), dim=1)
    ops["policy step"] = step


def _lanes(ops: dict[str, Callable[[], Any]]) -> None:
    """The lanes' kernels: one trunk forward of a padded batch of lanes, and batched head-only fits."""
    import torch

    from metadagger.imitation.head_fits import HeadFit, Prior, fit_heads
    from metadagger.policies import PolicyNet

    width, live = 32, 27
    frames = np.zeros((width, _SIZE, _SIZE, 3), dtype=np.uint8)
    frames[:live] = (_integers(live * _SIZE * _SIZE * 3, 9) & 255).astype(np.uint8).reshape(live, _SIZE, _SIZE, 3)
    net = PolicyNet(obs_shape=(_SIZE, _SIZE, 3), n_outputs=_CLASSES, discrete=True)
    net.init_weights(0)

    def forward() -> torch.Tensor:
        with torch.inference_mode():
            return net.trunk(net.preprocess(torch.from_numpy(frames)))

    def fits(discrete: bool) -> list[torch.Tensor]:
        out_dim = _CLASSES if discrete else 3
        heads = []
        for k, n in enumerate((40, 25, 10)):  # fits of unequal length: heads drop out as they end
            orders = np.argsort(_integers(3 * n, 10 + k).reshape(3, n), axis=1, kind="stable")
            targets = _integers(n, 40 + k) % _CLASSES
            head = torch.from_numpy(_uniform((out_dim * 513,), 20 + k))
            heads.append(
                HeadFit(
                    head=head,
                    features=torch.from_numpy(_uniform((n, 512), 30 + k)),
                    targets=torch.from_numpy(targets.astype(np.int64) if discrete else _uniform((n, out_dim), 50 + k)),
                    orders=torch.from_numpy(orders),
                    lr=1e-3,
                    weight_decay=1e-4,
                    batch_size=10,
                    called=f"fingerprint fit {k}",
                    prior=None if discrete else Prior(mean=head.flip(0), weight=torch.full_like(head, 0.25)),
                )
            )
        return [fitted.head for fitted in fit_heads(heads, out_dim=out_dim, discrete=discrete)]

    ops["lanes: trunk forward (32 rows, 5 padded)"] = forward
    ops["lanes: batched head fits"] = lambda: fits(discrete=True)
    ops["lanes: batched head fits (action vectors, a prior)"] = lambda: fits(discrete=False)


def _gates(ops: dict[str, Callable[[], Any]]) -> None:
    """The scores of the gates that compute more than a comparison: neighbour distances, the
    ensemble's disagreement and the learner's entropy, on a round of 200 states, 300 labelled."""
    import torch

    from metadagger.imitation.gate_registry import make_gate
    from metadagger.imitation.gate_view import Labelled, LearnerView

    features = torch.from_numpy(_uniform((200, 64), 60))
    labels = torch.from_numpy((_integers(300, 61) % _CLASSES).astype(np.int64))
    labelled = Labelled(torch.from_numpy(_uniform((300, 64), 62)), labels, labels.clone())
    head = torch.from_numpy(_uniform((_CLASSES * 65,), 63)) * 8

    def scores() -> list[torch.Tensor]:
        view = LearnerView.of(features, head, labelled, generator=torch.Generator().manual_seed(0))
        return [make_gate(name, 0.5).scores(view) for name in ("novelty", "ensemble", "entropy")]

    ops["gates: novelty, ensemble and entropy scores"] = scores


def _carracing_episode(ops: dict[str, Callable[[], Any]]) -> None:
    from metadagger.cli.bench_env import smooth_actions
    from metadagger.tasks import make_task

    def frames() -> list[np.ndarray]:
        env = make_task("carracing").make_base_env()
        try:
            obs, _ = env.reset(seed=0)
            seen = [obs]
            for action in smooth_actions(0, _EPISODE_STEPS):
                obs, *_ = env.step(action)
                seen.append(obs)
            return seen
        finally:
            env.close()

    ops["carracing frames (Box2D, OpenCV)"] = frames


def fingerprint_kernels() -> dict[str, Any]:
    """The fingerprint of each computation, in the order a run meets them, with this machine's
    description, its kernel stamp and the commit that computed it."""
    import torch

    torch.set_num_threads(1)  # as every stage computes
    ops: dict[str, Callable[[], Any]] = {}
    _numpy_and_opencv(ops)
    _policy_step(ops)
    _lanes(ops)
    _gates(ops)
    _carracing_episode(ops)
    digests: list[dict[str, Any]] = []
    for name, op in ops.items():
        value = op()
        parts = value.items() if isinstance(value, dict) else [(None, value)]
        digests += [_digest(name if part is None else f"{name}: {part}", v) for part, v in parts]
    return {
        "ops": digests,
        "kernels": kernel_stamp(),
        "machine": machine_description(),
        "commit": source_revision() or "unknown",
    }


def read_fingerprint(path: Path) -> dict[str, Any]:
    """A fingerprint file written by ``metadagger bench ops``; a UserError if it is not one."""
    fix = "write one on the other machine with `metadagger bench ops --out FILE` and pass that file"
    if not Path(path).is_file():
        raise UserError(f"no kernel fingerprint at {path}: {fix}")
    try:
        data = read_json(path, called="a kernel fingerprint")
    except UserError:
        raise UserError(f"{path} is not a kernel fingerprint (it does not read as JSON); {fix}") from None
    ops = data.get("ops") if isinstance(data, dict) else None
    if not isinstance(ops, list) or not all(isinstance(v, dict) and {"op", "sha256"} <= v.keys() for v in ops):
        raise UserError(f"{path} is not a kernel fingerprint (no list of ops with their sha256); {fix}")
    return data


def compare_fingerprints(mine: dict[str, Any], other: dict[str, Any]) -> dict[str, Any]:
    """Which computations give other bits in ``other`` than in ``mine``, in run order, the first
    of them, and those only one side has."""
    ours, theirs = ({entry["op"]: entry["sha256"] for entry in side["ops"]} for side in (mine, other))
    shared = [name for name in ours if name in theirs]
    differ = [name for name in shared if ours[name] != theirs[name]]
    return {
        "other_cpu": other.get("machine", {}).get("cpu"),
        "same": len(shared) - len(differ),
        "differ": differ,
        "first_difference": differ[0] if differ else None,
        "only_here": [name for name in ours if name not in theirs],
        "only_there": [name for name in theirs if name not in ours],
    }


__all__ = ["compare_fingerprints", "fingerprint_kernels", "read_fingerprint"]
