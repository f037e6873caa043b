"""Step-throughput benchmarks: the same as ``mjxcpg bench`` (see README.md beside this file).

    python bench/throughput.py --json > bench/results/$(date -u +%F)-cpu$(nproc).json
"""

import sys

from mjxcpg import xla
from mjxcpg.cli import main

if __name__ == "__main__":
    xla.one_cpu_thread()  # as the mjxcpg program does
    sys.exit(main(["bench", *sys.argv[1:]]))
