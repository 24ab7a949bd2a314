"""`python -m ratouch.cli`: the `ratouch` command."""

import sys

from ratouch.cli import main

sys.exit(main())
