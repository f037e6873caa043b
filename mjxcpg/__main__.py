import sys

from mjxcpg.cli import main

sys.exit(main())
