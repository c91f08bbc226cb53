"""One seed's rollouts side by side on the toy corridor: the benchmark's rollouts, readable MP4 and GIF."""

from __future__ import annotations

import numpy as np
import pytest
from toy_task import CorridorTask

from metadagger.errors import UserError
from metadagger.evaluation.benchmark import seed_chains as bench
from metadagger.evaluation.benchmark.config import BenchmarkConfig
from metadagger.evaluation.benchmark.methods import BCKey, MapperKey, RoundKey
from metadagger.evaluation.video import BAND, check_methods, compose, learner_view, seed_clips, write_video
from metadagger.imitation.bc import BCConfig
from metadagger.mapping.mappers import MapperFile
from metadagger.runfolder.stamps import file_fingerprint

imageio = pytest.importorskip("imageio.v2")
pytest.importorskip("imageio_ffmpeg")

BC = BCConfig(lr=1e-2, batch_size=10, epochs=1, head_only=True)
SEED, ROUNDS = 300, 2


@pytest.fixture(scope="module")
def clips(toy_run):
    return seed_clips(
        CorridorTask(),
        toy_run,
        SEED,
        ["expert", "bc", "pistar-head", "dagger"],
        bc=BC,
        dagger_bc=BC,
        rounds=ROUNDS,
        early_stop=None,
    )


def test_each_clip_is_the_rollout_its_benchmark_row_is_made_of(toy_run, clips):
    keys = (
        BCKey("bc", ""),
        MapperKey("mdm-pistar-head", "", kind="pistar-head"),
        RoundKey("dagger", str(ROUNDS), round=ROUNDS),
    )
    mapper = MapperFile(str(toy_run.mapper("pistar-head")), file_fingerprint(toy_run.mapper("pistar-head")))
    job = bench.BenchmarkJob(
        task=CorridorTask(),
        pistar=str(toy_run.pistar),
        seed=SEED,
        methods=tuple(k.id for k in keys),
        keys=keys,
        mappers={"pistar-head": mapper},
        config=BenchmarkConfig(seeds=(SEED,)),
        rounds=ROUNDS,
        bc=BC,
        dagger_bc=BC,
        early_stop=None,
        mdi=None,
    )
    rows = [bench.benchmark_seed(job)["entries"][k.id][0] for k in keys]
    expert, *shown = clips
    assert expert.label == "expert" and expert.queries == expert.trajectory.steps
    for clip, row in zip(shown, rows):
        assert (clip.trajectory.steps, clip.trajectory.success, clip.queries) == (
            row["steps"],
            row["success"],
            row["expert_queries"],
        )
    assert [c.label for c in clips] == ["expert", "BC", "MDM pi*-head (control)", f"DAgger, {ROUNDS} rounds"]


def test_frames_hold_each_finished_episode_and_encode_to_mp4_and_gif(clips, tmp_path):
    frames = compose(clips, scale=2)
    longest = max(c.trajectory.steps for c in clips)
    assert len(frames) == longest + 1
    height, width, _ = frames[0].shape
    size = clips[0].trajectory.obs.shape[1] * 2
    assert width >= len(clips) * size + 3 * 4 and height >= size + BAND and height % 2 == 0 == width % 2
    shortest = min(range(len(clips)), key=lambda i: clips[i].trajectory.steps)
    column = slice(shortest * (size + 4), shortest * (size + 4) + size)
    assert all(np.array_equal(frames[-1][:, column], f[:, column]) for f in frames[clips[shortest].trajectory.steps :])
    mp4, gif = write_video(frames, tmp_path / "v.mp4", tmp_path / "v.gif", fps=10, gif_stride=3)
    assert len(imageio.mimread(mp4, format="FFMPEG", memtest=False)) == len(frames)
    read = imageio.mimread(gif, format="GIF")
    assert len(read) == len(frames[::3]) + (1 if (len(frames) - 1) % 3 else 0)
    assert read[0].shape[:2] == (height, width)


def test_learner_view_and_bad_methods(toy_run):
    grey = np.arange(2 * 2 * 4, dtype=np.uint8).reshape(2, 2, 4)  # four stacked grey frames: the last one shown
    assert np.array_equal(learner_view(grey), np.repeat(grey[..., 3:], 3, axis=-1))
    with pytest.raises(
        UserError,
        match="--methods has magic, which run .* cannot show; expected some of expert, bc, dagger, pistar-head",
    ):
        check_methods(["bc", "magic"], toy_run)
    with pytest.raises(UserError, match="--methods lists a method twice"):
        check_methods(["bc", "bc"], toy_run)
