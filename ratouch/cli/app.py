"""`ratouch app`: launch the Gradio app.
"""

from __future__ import annotations

import argparse
import os
import sys

from ratouch.cli.common import usage
from ratouch.paths import APP_FILE


def run(args: argparse.Namespace) -> int:
    app_file = APP_FILE
    if not app_file.is_file():
        raise usage(f"the app is not found at {app_file} (run from a checkout of the repo)")
    os.execv(sys.executable, [sys.executable, str(app_file), "--host", args.host,
                              "--port", str(args.port)])
    return 0  # not reached
