"""Direct mapping (MDM) and one-shot evaluation on unseen seeds (paper 4.1, Tables 1-5).

Per seed: the seed's expert demonstration -> a head fitted by BC on pi*'s frozen trunk (exactly as
for the pairs) -> each method's head (the BC head itself, each mapper's output, the controls) ->
one rollout each. One-shot: for each mapper whose head failed, its output initialises the head,
which is refitted once on the same demonstration and rolled out again. Every evaluated head is
saved (``eval/heads/<method>/<seed>.safetensors``, tensor ``head``) so any row can be replayed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from metadagger.errors import UserError
from metadagger.evaluation.rows import RowLog, write_csv
from metadagger.imitation.bc import BCConfig, FeatureCache, fit_bc
from metadagger.imitation.rollouts import rollout
from metadagger.io import save_tensors
from metadagger.mapping.mappers import cached_mapper
from metadagger.metal.groundtruth import cached_groundtruth, head_from_groundtruth
from metadagger.parallel import make_executor
from metadagger.tasks.base import Task

MAPPER_METHODS = ("dm", "sam", "tam", "mean-da", "pistar-head")


@dataclass(frozen=True)
class EvalConfig:
    """Which unseen seeds and methods are evaluated."""

    seeds: tuple[int, ...] = tuple(range(5000, 5020))
    """Unseen seeds (never used for pi* or pairs); the paper uses 20."""
    methods: tuple[str, ...] = MAPPER_METHODS
    """Mappers evaluated beside BC: dm, sam, tam and the controls mean-da and pistar-head."""
    oneshot: bool = True
    """Also run one-shot learning for every mapper that fails on a seed (Tables 3-5)."""

    def __post_init__(self) -> None:
        if not self.seeds:
            raise UserError("evaluate.seeds must not be empty")
        unknown = sorted(set(self.methods) - set(MAPPER_METHODS))
        if unknown:
            raise UserError(f"evaluate.methods has unknown method(s) {unknown}; allowed: {', '.join(MAPPER_METHODS)}")


@dataclass(frozen=True)
class EvalJob:
    """One seed's evaluation (picklable)."""

    task: Task
    groundtruth: str
    mappers: dict[str, str]
    seed: int
    bc: BCConfig
    oneshot: bool


def evaluate_seed(job: EvalJob) -> dict[str, Any]:
    """Evaluate BC, every mapper and their one-shot refits on one seed."""
    policy = head_from_groundtruth(cached_groundtruth(job.groundtruth), job.seed)
    bc_config = dataclasses.replace(job.bc, seed=job.seed)
    env = job.task.make_env()
    rows: list[dict[str, Any]] = []
    heads: dict[str, np.ndarray] = {}

    def run(method: str, head: np.ndarray, queries: int) -> bool:
        policy.load_head_vector(torch.from_numpy(head))
        traj = rollout(env, seed=job.seed, policy=policy)
        heads[method] = head
        rows.append({"method": method, "seed": job.seed, "success": bool(traj.success), "reward": float(traj.reward),
                     "steps": int(traj.steps), "expert_queries": queries})
        return bool(traj.success)

    try:
        demo = rollout(env, seed=job.seed, policy=None).to_dataset()
        cache = FeatureCache(policy)
        fit_bc(policy, demo, bc_config, cache=cache)
        w_bc = policy.head_vector().numpy().copy()
        run("bc", w_bc, len(demo))
        failed = [m for m, path in job.mappers.items() if not run(m, cached_mapper(path)(w_bc), len(demo))]
        for method in failed if job.oneshot else []:
            policy.load_head_vector(torch.from_numpy(heads[method]))
            fit_bc(policy, demo, bc_config, cache=cache)
            # one-shot reuses the same demonstration: no further expert queries
            run(f"oneshot-{method}", policy.head_vector().numpy().copy(), len(demo))
    finally:
        env.close()
    return {"seed": job.seed, "rows": rows, "heads": heads}


def mapper_path(run: str | Path, kind: str) -> Path:
    """Where the mapper of ``kind`` of a run lives."""
    return Path(run) / "mappers" / kind / "mapper.safetensors"


def evaluate_run(
    task: Task,
    run: str | Path,
    config: EvalConfig,
    *,
    groundtruth: str | Path,
    bc: BCConfig,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Evaluate every seed of ``config`` not evaluated yet; return all rows of those seeds and
    write ``eval/mdm.csv`` (BC + mappers) and, when ``config.oneshot``, ``eval/oneshot.csv``."""
    run = Path(run)
    mappers = {m: str(mapper_path(run, m)) for m in config.methods}
    missing = [m for m, p in mappers.items() if not Path(p).is_file()]
    if missing:
        raise UserError(f"mappers not trained yet: {', '.join(missing)}; run `metadagger train-mapper --out {run} --kind all` first")
    log = RowLog(run / "eval" / "rows.jsonl")
    todo = [s for s in config.seeds if s not in log.done_seeds()]
    jobs = [EvalJob(task=task, groundtruth=str(groundtruth), mappers=mappers, seed=s, bc=bc, oneshot=config.oneshot) for s in todo]
    if jobs:
        with make_executor(executor, workers=workers, address=address) as pool:
            for result in tqdm(pool.imap_unordered(evaluate_seed, jobs), total=len(jobs), desc="evaluate", disable=not progress):
                for method, head in result["heads"].items():
                    save_tensors(run / "eval" / "heads" / method / f"{result['seed']}.safetensors", {"head": torch.from_numpy(head)})
                log.append(result["seed"], result["rows"])
    rows = [r for r in log.rows() if r["seed"] in set(config.seeds)]
    write_csv(run / "eval" / "mdm.csv", [r for r in rows if not r["method"].startswith("oneshot-")])
    if config.oneshot:
        write_csv(run / "eval" / "oneshot.csv", [r for r in rows if r["method"].startswith("oneshot-")])
    return rows
