"""Step-throughput benchmarks: the same as ``mjxcpg bench`` (see README.md beside this file).

    python bench/throughput.py --json > bench/results/$(date -u +%F)-cpu$(nproc).json
"""

import sys

from mjxcpg.cli import entry

if __name__ == "__main__":
    sys.exit(entry(["bench", *sys.argv[1:]]))
