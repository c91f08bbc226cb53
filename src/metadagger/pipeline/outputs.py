"""What a run folder gives beyond its stages: its episodes as a Minari dataset, and videos of
methods side by side. Each checks, as a stage does, that pi* and the mappers it reads are current."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from metadagger.errors import UserError
from metadagger.evaluation.video import FIXED_METHODS, check_methods, compose, require_imageio, seed_clips, write_video
from metadagger.metal_dagger.export import DEFAULT_AUTHOR, export_run
from metadagger.pipeline.run_config import RunConfig
from metadagger.pipeline.stage_inputs import run_task, stage_inputs
from metadagger.pipeline.stage_runs import records_config
from metadagger.runfolder.driver import StageOptions
from metadagger.runfolder.layout import RunLayout
from metadagger.runfolder.lock import run_lock


@records_config
def stage_export(
    layout: RunLayout,
    config: RunConfig,
    *,
    content: str,
    name: str,
    seeds: Sequence[int] | None = None,
    author: str = DEFAULT_AUTHOR,
    author_email: str | None = None,
    options: StageOptions = StageOptions(),
) -> dict:
    """The run's ``content`` episodes (demos, dagger, pairs-data) of ``seeds`` (default: the pair
    seeds) as the Minari dataset ``name``, by ``author`` (:mod:`metadagger.metal_dagger.export`)."""
    # the demonstrations need no pi*; the other contents are rolled out with it
    task = run_task(config) if content == "demos" else stage_inputs(layout, config).task
    return export_run(
        task,
        layout,
        config.pairs,
        content=content,
        name=name,
        seeds=sorted(set(config.pairs.seeds if seeds is None else seeds)),
        author=author,
        author_email=author_email,
        options=options,
    )


def stage_video(
    layout: RunLayout,
    config: RunConfig,
    *,
    seed: int,
    methods: Sequence[str],
    fps: int = 30,
    scale: int = 3,
    gif_stride: int = 3,
) -> tuple[Path, Path]:
    """``methods`` rolled out on ``seed`` side by side (:mod:`metadagger.evaluation.video`), as
    ``RUN/videos/<seed>-<methods>.mp4`` and ``.gif``; returns their paths."""
    if fps < 1 or scale < 1 or gif_stride < 1:
        raise UserError(f"--fps, --scale and --gif-stride must be >= 1, got {fps}, {scale} and {gif_stride}")
    require_imageio()
    check_methods(methods, layout)
    inputs = stage_inputs(layout, config, mappers=[m for m in methods if m not in FIXED_METHODS], checked=True)
    clips = seed_clips(
        inputs.task,
        layout,
        seed,
        methods,
        bc=config.pairs.bc,
        dagger_bc=config.pairs.dagger_bc,
        rounds=config.pairs.dagger_rounds,
        early_stop=config.pairs.early_stop,
    )
    stem = layout.root / "videos" / f"{seed}-{'-'.join(methods)}"
    with run_lock(layout.root):
        return write_video(
            compose(clips, scale=scale),
            stem.with_suffix(".mp4"),
            stem.with_suffix(".gif"),
            fps=fps,
            gif_stride=gif_stride,
        )
