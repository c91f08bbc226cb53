"""The demo: BC from expert demonstrations, then DAgger rounds, both evaluated on unseen seeds.

Read it top to bottom: collect demos -> fit BC -> evaluate -> DAgger (evaluate after every round)
-> write the table, the per-round CSV and the success-vs-round plot to ``<out>/demo/``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from metadagger.errors import UserError
from metadagger.evaluation.rows import write_csv
from metadagger.imitation.bc import BCConfig, fit_bc
from metadagger.imitation.collect import collect
from metadagger.imitation.data import Dataset
from metadagger.imitation.episodes import evaluate_policy
from metadagger.imitation.metrics import summarize
from metadagger.imitation.minari_io import read_demonstrations
from metadagger.imitation.whole_policy_dagger import DAggerConfig, run_whole_policy_dagger
from metadagger.pipeline.run_config import load_preset
from metadagger.policies import make_policy
from metadagger.runfolder.layout import RunLayout
from metadagger.tasks import make_task
from metadagger.tasks.base import Task
from metadagger.utils.io import write_json, write_text
from metadagger.utils.yaml_config import build, dump_yaml


@dataclass(frozen=True)
class DemoConfig:
    """BC vs DAgger on one task."""

    task: str = "carracing"
    """Task name (``metadagger.make_task``)."""
    train_seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    """Seeds of the expert demonstrations and of every DAgger round."""
    eval_seeds: tuple[int, ...] = tuple(range(1000, 1010))
    """Unseen seeds both policies are evaluated on."""
    dagger_rounds: int = 3
    """DAgger rounds after the BC fit."""
    bc: BCConfig = field(default_factory=lambda: BCConfig(epochs=5))
    """The supervised fit used by BC and by every DAgger round."""
    max_episode_steps: int = 1000
    """Step limit of every episode."""
    seed: int = 0
    """Seed of the policy's initial weights."""
    demos: str | None = None
    """A Minari dataset id to clone from instead of the expert's demonstrations of ``train_seeds``
    (any dataset whose spaces match the task's learner; DAgger still rolls out ``train_seeds``)."""

    def __post_init__(self) -> None:
        if not self.train_seeds or not self.eval_seeds:
            raise UserError("DemoConfig: train_seeds and eval_seeds must both be non-empty")
        shared = sorted(set(self.train_seeds) & set(self.eval_seeds))
        if shared:
            raise UserError(
                f"DemoConfig: eval_seeds must be unseen, but {shared} are also train_seeds; pick disjoint ranges"
            )
        if self.dagger_rounds < 1:
            raise UserError(f"DemoConfig.dagger_rounds must be >= 1, got {self.dagger_rounds}")
        if self.max_episode_steps < 1:
            raise UserError(f"DemoConfig.max_episode_steps must be >= 1, got {self.max_episode_steps}")


def demo_config(
    task: str, preset: str, *, rounds: int | None = None, epochs: int | None = None, demos: str | None = None
) -> DemoConfig:
    """The demo section of a task's preset, with optional overrides (validated like the preset)."""
    data = {"task": task, **load_preset(task, preset).get("demo", {})}
    if demos is not None:
        data["demos"] = demos
    if rounds is not None:
        data["dagger_rounds"] = rounds
    if epochs is not None:
        data["bc"] = {**data.get("bc", {}), "epochs": epochs}
    return build(DemoConfig, data, where="demo")


@dataclass(frozen=True)
class DemoResult:
    folder: Path
    table: str
    rounds: list[dict]


def run_demo(config: DemoConfig, out: str | Path, *, progress: bool = True) -> DemoResult:
    """Run the demo and write its artifacts under ``<out>/demo/``."""
    out = Path(out)
    folder = RunLayout(out).demo_dir
    task = make_task(config.task, max_episode_steps=config.max_episode_steps)

    data = _demonstrations(
        task, config, progress=progress
    )  # a dataset that does not fit is refused before anything is written
    write_text(folder / "config.yaml", dump_yaml(config))
    demo_queries = len(data)

    policy = make_policy(task, seed=config.seed)
    fit_bc(policy, data, config.bc, progress=progress)
    policy.save(folder / "bc.safetensors")
    bc_rows = evaluate_policy(task, policy, config.eval_seeds, label="eval BC", progress=progress)
    curve = [{"round": 0, **summarize(bc_rows), "expert_queries": demo_queries}]
    dagger_rows: list[dict] = []

    def on_round(round_idx: int, current, metrics: dict) -> None:
        rows = evaluate_policy(task, current, config.eval_seeds, label=f"eval round {round_idx}", progress=progress)
        curve.append({"round": round_idx, **summarize(rows), "expert_queries": int(metrics["dagger/expert_queries"])})
        if round_idx == config.dagger_rounds:
            dagger_rows.extend(rows)

    dagger_policy = policy.copy()
    run_whole_policy_dagger(
        dagger_policy,
        task,
        config.train_seeds,
        initial=data,
        config=DAggerConfig(rounds=config.dagger_rounds, bc=config.bc),
        progress=progress,
        on_round=on_round,
    )
    dagger_policy.save(folder / "dagger.safetensors")

    table = _table(
        summarize(bc_rows), demo_queries, summarize(dagger_rows), curve[-1]["expert_queries"], len(config.eval_seeds)
    )
    write_text(folder / "table.md", table + "\n")
    write_json(folder / "metrics.json", {"bc": bc_rows, "dagger": dagger_rows, "curve": curve})
    write_csv(folder / "rounds.csv", curve, fields=tuple(curve[0]))
    _plot(curve, folder / "success_vs_round.png", task=config.task)
    return DemoResult(folder=folder, table=table, rounds=curve)


def _demonstrations(task: Task, config: DemoConfig, *, progress: bool) -> Dataset:
    """The expert's demonstrations of ``train_seeds``, or the rows of the Minari dataset ``demos``."""
    if config.demos is None:
        demos = collect(task, config.train_seeds, policy=None, progress=progress)
        return Dataset.concat(*[t.to_dataset() for t in demos])
    env = task.make_env()
    try:
        return read_demonstrations(config.demos, observation_space=env.observation_space, action_space=env.action_space)
    finally:
        env.close()


def _table(bc: dict, bc_queries: int, da: dict, da_queries: int, n_eval: int) -> str:
    lines = [
        f"| method | success ({n_eval} unseen seeds) | 95% CI | mean reward | mean steps | expert queries |",
        "|---|---|---|---|---|---|",
    ]
    for name, s, q in (("BC", bc, bc_queries), ("DAgger", da, da_queries)):
        lines.append(
            f"| {name} | {s['success_rate']:.0%} ({s['successes']}/{s['episodes']}) | "
            f"{s['success_ci_low']:.0%}-{s['success_ci_high']:.0%} | {s['mean_reward']:.1f} | {s['mean_steps']:.0f} | "
            f"{q} |"
        )
    return "\n".join(lines)


def _plot(curve: list[dict], path: Path, *, task: str) -> None:
    from metadagger.utils.plotting import plt, save_figure

    fig, ax = plt.subplots(figsize=(5, 3.5))
    rounds = [r["round"] for r in curve]
    ax.plot(rounds, [r["success_rate"] for r in curve], marker="o", label="success rate")
    ax.fill_between(
        rounds,
        [r["success_ci_low"] for r in curve],
        [r["success_ci_high"] for r in curve],
        alpha=0.2,
        label="95% Wilson CI",
    )
    ax.set_xlabel("DAgger round (0 = BC)")
    ax.set_ylabel("success on unseen seeds")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xticks(rounds)
    ax.set_title(f"{task}: BC then DAgger")
    ax.legend(loc="lower right")
    save_figure(fig, path)
