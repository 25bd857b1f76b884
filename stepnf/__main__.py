import sys

from stepnf.cli.console import main

sys.exit(main())
