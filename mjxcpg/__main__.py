import sys

from mjxcpg.cli import entry

sys.exit(entry())
