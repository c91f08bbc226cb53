"""Train Fetch's pi* for one lever setting (docs/fetch.md, "pi* that generalises") and measure it on its own seeds and on validation seeds.

Validation seeds 20000-... are unseen by pi* and are neither pi*'s eval_seeds (10000-...) nor
MDI seeds (5000-...); levers are chosen on them.
usage: python scripts/fetch_pistar_lever.py RUN_FOLDER --seeds 0-39 --epochs 16 --rounds 5 --shift 0 [--arch JSON] [--val 20000-20049]
"""
import argparse, json, time
from pathlib import Path
import torch
torch.set_num_threads(1)
from metadagger.config import parse_seeds
from metadagger.tasks import make_task
from metadagger.imitation.bc import BCConfig
from metadagger.imitation.episodes import evaluate_policy
from metadagger.imitation.metrics import summarize
from metadagger.metal.groundtruth import GroundTruthConfig, train_groundtruth, groundtruth_path
from metadagger.policies import load_policy

ap = argparse.ArgumentParser()
ap.add_argument("name"); ap.add_argument("--seeds", default="0-39"); ap.add_argument("--epochs", type=int, default=16)
ap.add_argument("--rounds", type=int, default=5); ap.add_argument("--shift", type=int, default=0)
ap.add_argument("--arch", default=None); ap.add_argument("--val", default="20000-20049"); ap.add_argument("--lr", type=float, default=1e-3)
a = ap.parse_args()
task = make_task("fetch", max_episode_steps=50)
if a.arch:
    task.policy_arch = {**task.policy_arch, **json.loads(a.arch)}
cfg = GroundTruthConfig(seeds=parse_seeds(a.seeds), eval_seeds=(), dagger_rounds=a.rounds,
                        bc=BCConfig(lr=a.lr, batch_size=64, epochs=a.epochs, augment_shift=a.shift))
run = Path(a.name)  # a run folder; its groundtruth/ is resumed if present
t0 = time.perf_counter()
m = train_groundtruth(task, cfg, run, progress=False)
t1 = time.perf_counter()
pol = load_policy(groundtruth_path(run))
val = summarize(evaluate_policy(task, pol, parse_seeds(a.val), label="val", progress=False))
t2 = time.perf_counter()
own = m["own_seeds"]
out = {"name": a.name, "args": vars(a), "own": f"{own['successes']}/{own['episodes']}", "own_ci": [own["success_ci_low"], own["success_ci_high"]],
       "val": f"{val['successes']}/{val['episodes']}", "val_ci": [val["success_ci_low"], val["success_ci_high"]],
       "train_plus_own_eval_s": t1 - t0, "val_eval_s": t2 - t1, "params": sum(p.numel() for p in pol.net.parameters())}
(run / "sweep.json").write_text(json.dumps(out, indent=1))
print(json.dumps(out))
