import sys

from formation_ilc.cli.commands import main

sys.exit(main())
