"""How many batch shapes (each a compilation of the chunk) a process of a many-process sweep
runs, in a simulation where the learners finish one per chunk, in a random order.

Today's rule: each process compacts its own block (``train.compacted_size`` of its own
unfinished learners), so its shapes are its block's ladder: the block, and the powers of two
from 2 to half the block, ``1 + floor(log2(block / 2))`` in all (7 for a block of 128).
Beside it, the rule of the earlier design, simulated: one compaction over the whole batch
(``train.compacted_rows``), each process stepping the compacted rows that fall in its block,
a lone row beside a copy of itself.

    .venv/bin/python bench/compiled_shapes.py --learners 1024 --processes 8
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from mjxcpg.training.train import compacted_rows, compacted_size


def shapes_per_process(learners: int, processes: int, seed: int) -> dict[str, list[int]]:
    order = np.random.default_rng(seed).permutation(learners)  # who finishes at each chunk
    blocks = np.array_split(np.arange(learners), processes)
    done = np.zeros(learners, bool)
    own = [set() for _ in blocks]
    global_rule = [set() for _ in blocks]
    for finished in order:
        rows = compacted_rows(done)
        rows = np.arange(learners) if rows is None else rows
        for p, block in enumerate(blocks):
            active = int(np.sum(~done[block]))
            if active:
                own[p].add(compacted_size(active, len(block)))
            mine = np.intersect1d(rows, block)
            if len(mine):
                global_rule[p].add(max(len(mine), 2))
        done[finished] = True
    return {"own_block": [len(s) for s in own], "global_compaction": [len(s) for s in global_rule]}


def ladder_bound(block: int) -> int:
    """The shapes of one block's ladder: the block, and 2, 4, ... up to half of it."""
    return 1 + max(0, int(np.floor(np.log2(block // 2)))) if block >= 4 else 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--learners", type=int, default=1024)
    parser.add_argument("--processes", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    counts = shapes_per_process(args.learners, args.processes, args.seed)
    block = args.learners // args.processes
    print(json.dumps({"learners": args.learners, "processes": args.processes, "block": block,
                      "ladder_bound": ladder_bound(block), **counts}))


if __name__ == "__main__":
    main()
