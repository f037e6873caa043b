"""``mjxcpg transfer`` for final weights saved by ``bench/dump_final_weights.py``, walked on
both engines by this version's code (the run's config gives the set-up), for some learners
only and as many walks as asked:

    NPROC=1 .venv/bin/python bench/transfer_weights.py runs/printed_mjx_today /tmp/w.npz --learners 1 --walks 64
"""

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from mjxcpg.evaluation import transfer
from mjxcpg.learning.actor_critic import Weights
from mjxcpg.report import learning as report
from mjxcpg.training import runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="the run directory, for its config.json")
    parser.add_argument("weights", type=Path, help="the .npz of bench/dump_final_weights.py")
    parser.add_argument("--walks", type=int, default=8)
    parser.add_argument("--learners", type=int, nargs="+", help="only these learners (default: all)")
    parser.add_argument("--out", type=Path, help="write the result here as JSON")
    args = parser.parse_args()
    spec, record = runs.read_config(args.run)
    saved = np.load(args.weights)
    chosen = np.array(args.learners if args.learners else range(len(spec.k_s)))
    spec = dataclasses.replace(spec, k_s=tuple(spec.k_s[k] for k in chosen), seeds=tuple(spec.seeds[k] for k in chosen))
    weights = Weights(critic=saved["critic"][chosen], mean=saved["mean"][chosen], sigma=saved["sigma"][chosen])
    result = transfer.compare_engines(spec, weights, saved["trials_to_success"][chosen] >= 0, record["engine"],
                                      walks=args.walks, learners=chosen.tolist())
    for r in result["learners"]:
        print(transfer.row_line(r, args.walks))
    print(json.dumps({k: v for k, v in report.json_safe(result).items() if k != "learners"}))
    if args.out:
        args.out.write_text(json.dumps(report.json_safe(result), indent=1))


if __name__ == "__main__":
    main()
