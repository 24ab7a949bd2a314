"""RA-Touch Explorer's Gradio app: only the UI; every number comes from `ratouch`.

`build_demo(pipeline)` and `main(argv)` live in `app.app`; importing this package loads
neither gradio nor any model (they are imported on first use of these names).
"""

from __future__ import annotations

__all__ = ["build_demo", "main"]


def __getattr__(name: str):
    if name in __all__:
        from app import app as _app

        return getattr(_app, name)
    raise AttributeError(f"module 'app' has no attribute {name!r}")
