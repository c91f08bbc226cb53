"""Measure a saved Fetch policy on seed ranges ("-" skips one): fetch_pistar_eval.py CKPT OWN_SEEDS OTHER_SEEDS"""
import json, sys, time
import torch
torch.set_num_threads(1)
from metadagger.config import parse_seeds
from metadagger.tasks import make_task
from metadagger.imitation.episodes import evaluate_policy
from metadagger.imitation.metrics import summarize
from metadagger.policies import load_policy
ckpt, own, val = sys.argv[1:4]
task = make_task("fetch", max_episode_steps=50)
pol = load_policy(ckpt)
out = {"ckpt": ckpt}
for name, seeds in (("own", own), ("val", val)):
    if seeds == "-":
        continue
    s = summarize(evaluate_policy(task, pol, parse_seeds(seeds), label=name, progress=False))
    out[name] = f"{s['successes']}/{s['episodes']}"; out[name + "_ci"] = [round(s["success_ci_low"], 3), round(s["success_ci_high"], 3)]
print(json.dumps(out))
