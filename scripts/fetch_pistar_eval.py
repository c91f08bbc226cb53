"""Measure a saved Fetch policy (pi* or one of its round checkpoints) on seed ranges.

usage: python scripts/fetch_pistar_eval.py CHECKPOINT OWN_SEEDS OTHER_SEEDS   ("-" skips a range)
e.g.   python scripts/fetch_pistar_eval.py runs/gt/a/pistar/rounds/round_2.safetensors 0-39 20000-20049
"""

from __future__ import annotations

import json
import sys

import torch

from metadagger.imitation.episodes import evaluate_policy
from metadagger.imitation.metrics import summarize
from metadagger.policies import load_policy
from metadagger.tasks import make_task
from metadagger.utils.yaml_config import parse_seeds


def main(checkpoint: str, own: str, other: str) -> dict:
    """Success with its 95% Wilson interval on each seed range given."""
    torch.set_num_threads(1)
    task = make_task("fetch", max_episode_steps=50)
    policy = load_policy(checkpoint)
    out: dict = {"checkpoint": checkpoint}
    for name, seeds in (("own", own), ("other", other)):
        if seeds != "-":
            s = summarize(evaluate_policy(task, policy, parse_seeds(seeds), label=name, progress=False))
            out[name] = f"{s['successes']}/{s['episodes']}"
            out[f"{name}_ci"] = [round(s["success_ci_low"], 3), round(s["success_ci_high"], 3)]
    return out


if __name__ == "__main__":
    print(json.dumps(main(*sys.argv[1:4])))
