"""One seed's rollouts side by side, as the learner saw them (``metadagger video``).

Each method's rollout is the one its benchmark row is made of: pi*'s trunk with the seed's
head, the pairs' early stop, the steps of :mod:`metadagger.metal_dagger.method`. A panel shows the
learner's observation at each step with the method, the step, the reward so far and the expert
queries the method spent on the seed; an episode that ends first holds its last frame under its
outcome. Frames are encoded by imageio (the ``video`` extra): an MP4 (ffmpeg, H.264) and a GIF.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from metadagger.errors import UserError
from metadagger.evaluation.benchmark.labels import method_label
from metadagger.evaluation.benchmark.methods import MDM_PREFIX, MapperKey
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.rollouts import Trajectory
from metadagger.mapping.mappers import MapperFile, cached_mapper
from metadagger.metal_dagger.method import (
    SeedLearner,
    bc_head,
    dagger_rounds,
    demonstration,
    map_head,
    seed_context,
    seeded,
)
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.stamps import file_fingerprint
from metadagger.tasks.base import Task
from metadagger.utils.io import atomic_write

#: Methods that are not a mapper kind: the expert's demonstration, w_BC, DAgger after R rounds.
FIXED_METHODS = ("expert", "bc", "dagger")
#: Height in pixels of the text band above each panel.
BAND = 36


@dataclass(frozen=True)
class Clip:
    """One method's rollout on the seed and what the method spent on it."""

    label: str
    trajectory: Trajectory
    queries: int


def check_methods(methods: Sequence[str], layout: RunLayout) -> None:
    """Raise a :class:`UserError` for an empty list, a repeat, or a method that is neither in
    :data:`FIXED_METHODS` nor a mapper kind the run has trained."""
    kinds = (
        sorted(p.name for p in (layout.root / "mappers").iterdir() if p.is_dir())
        if (layout.root / "mappers").is_dir()
        else []
    )
    allowed = [*FIXED_METHODS, *kinds]
    if not methods:
        raise UserError(f"--methods is empty; give some of {', '.join(allowed)}")
    if len(set(methods)) != len(methods):
        raise UserError(f"--methods lists a method twice: {','.join(methods)}; list each once")
    unknown = [m for m in methods if m not in allowed]
    if unknown:
        raise UserError(
            f"--methods has {', '.join(unknown)}, which run {layout.root} cannot show; expected some of "
            f"{', '.join(allowed)} (a mapper kind needs its mapper in {layout.root / 'mappers'})"
        )


def seed_clips(
    task: Task,
    layout: RunLayout,
    seed: int,
    methods: Sequence[str],
    *,
    bc: BCConfig,
    dagger_bc: BCConfig,
    rounds: int,
    early_stop: float | None,
) -> list[Clip]:
    """Each of ``methods`` rolled out on ``seed``, in order: ``expert`` (the demonstration),
    ``bc`` (w_BC), ``dagger`` (after ``rounds`` rounds) or a mapper kind (MDM from w_BC)."""
    with SeedLearner(task, str(layout.pistar), seed, head_init_seed=bc.head_init_seed(seed)) as learner:
        fresh = learner.head()
        demo = demonstration(learner)
        data = demo.to_dataset()
        w_bc = bc_head(learner, data, seeded(bc, seed))
        first = learner.roll(w_bc, early_stop=early_stop)
        clips: dict[str, Clip] = {"expert": Clip("expert", demo, len(data)), "bc": Clip("BC", first, len(data))}
        context = None
        for kind in (m for m in methods if m not in FIXED_METHODS):
            mapper = cached_mapper(MapperFile(str(layout.mapper(kind)), file_fingerprint(layout.mapper(kind))))
            if mapper.needs_context and context is None:
                context = seed_context(learner.cache, data.obs, first.obs)
            key = MapperKey(MDM_PREFIX + kind, "", kind=kind)
            clips[kind] = Clip(
                method_label(key.method),
                learner.roll(map_head(mapper, w_bc, context), early_stop=early_stop),
                len(data) if key.reads_demonstration else 0,
            )
        if "dagger" in methods:
            *_, last = dagger_rounds(
                learner,
                start=w_bc,
                first_rollout=first,
                demo=demo,
                rounds=rounds,
                fit=seeded(dagger_bc, seed),
                early_stop=early_stop,
                origin=fresh,
            )
            clips["dagger"] = Clip(f"DAgger, {rounds} rounds", last.rollout, last.queries)
    return [clips[m] for m in methods]


def learner_view(obs: np.ndarray) -> np.ndarray:
    """An observation (H, W, C) uint8 as an RGB image: RGB as it is, one channel or a stack of grey
    frames (C != 3) as the last frame in grey."""
    if obs.ndim == 2:
        obs = obs[..., None]
    if obs.shape[-1] == 3:
        return obs
    return np.repeat(obs[..., -1:], 3, axis=-1)


def panel(clip: Clip, t: int, scale: int) -> np.ndarray:
    """Clip ``clip`` at step ``t`` (held at its last frame past its end): the learner's view scaled
    by ``scale`` under a text band with the method, step, reward so far and queries."""
    from PIL import Image, ImageDraw

    traj = clip.trajectory
    done = t >= traj.steps
    obs = traj.final_obs if done else traj.obs[t]
    image = Image.fromarray(learner_view(np.asarray(obs))).resize(
        (obs.shape[1] * scale, obs.shape[0] * scale), Image.NEAREST
    )
    canvas = Image.new("RGB", (image.width, image.height + BAND), (0, 0, 0))
    canvas.paste(image, (0, BAND))
    steps = min(t + 1, traj.steps)
    reward = float(traj.step_rewards[:steps].sum())
    status = ("success" if traj.success else "failure") if done else f"step {steps}/{traj.steps}"
    draw = ImageDraw.Draw(canvas)
    draw.text((3, 1), clip.label, fill=(255, 255, 255))
    draw.text((3, 12), f"{status}  reward {reward:.1f}", fill=(255, 220, 120) if done else (220, 220, 220))
    draw.text((3, 23), f"expert queries {clip.queries}", fill=(160, 200, 255))
    return np.asarray(canvas)


def compose(clips: Sequence[Clip], *, scale: int = 3, gap: int = 4) -> list[np.ndarray]:
    """The side-by-side frames of ``clips``, as long as the longest episode plus one held frame;
    widths and heights even (as H.264 needs)."""
    length = max(c.trajectory.steps for c in clips) + 1
    frames = []
    for t in range(length):
        panels = [panel(c, t, scale) for c in clips]
        height = max(p.shape[0] for p in panels)
        spacer = np.zeros((height, gap, 3), dtype=np.uint8)
        row = np.concatenate(
            [part for p in panels for part in (np.pad(p, ((0, height - p.shape[0]), (0, 0), (0, 0))), spacer)][:-1],
            axis=1,
        )
        frames.append(np.pad(row, ((0, row.shape[0] % 2), (0, row.shape[1] % 2), (0, 0))))
    return frames


def require_imageio() -> tuple[Any, Any]:
    """imageio's v2 API and imageio-ffmpeg, or a :class:`UserError` saying how to install them."""
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg
    except ImportError:
        raise UserError(
            "metadagger video needs imageio and imageio-ffmpeg; install them with "
            "`pip install -e '.[video]' -c constraints.txt` (or `bash scripts/setup.sh video`)"
        ) from None
    return imageio, imageio_ffmpeg


def write_video(frames: Sequence[np.ndarray], mp4: Path, gif: Path, *, fps: int, gif_stride: int) -> tuple[Path, Path]:
    """``frames`` as an H.264 MP4 at ``fps`` and a looping GIF of every ``gif_stride``-th frame (and
    the last) at the same speed, each written atomically."""
    imageio, imageio_ffmpeg = require_imageio()
    height, width = frames[0].shape[:2]

    def encode(path: Path) -> None:
        writer = imageio_ffmpeg.write_frames(
            str(path),
            (width, height),
            fps=fps,
            codec="libx264",
            pix_fmt_out="yuv420p",
            macro_block_size=1,
            output_params=["-f", "mp4"],
        )
        writer.send(None)
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
        writer.close()

    atomic_write(mp4, encode)
    shown = list(frames[::gif_stride]) + ([frames[-1]] if (len(frames) - 1) % gif_stride else [])
    atomic_write(
        gif, lambda path: imageio.mimwrite(path, shown, format="GIF", duration=1000 * gif_stride / fps, loop=0)
    )
    return mp4, gif
