"""What several command modules share: the one-line usage error and the world configuration
(with its stress knobs) from the command line.
"""

from __future__ import annotations

import argparse

from ratouch.errors import RATouchError
from ratouch.world.config import StressConfig, WorldConfig


class UsageError(RATouchError):
    pass


def usage(msg: str) -> UsageError:
    return UsageError(msg)


def world_cfg(args: argparse.Namespace):
    stress = StressConfig(
        object_scale=args.object_scale, clutter=args.clutter,
        background_dominance=args.background_dominance, tactile_noise=args.tactile_noise,
        tactile_blur=args.tactile_blur, tactile_rotation=args.tactile_rotation,
        box_offset=args.box_offset, missing=args.missing, no_contact=args.no_contact)
    return WorldConfig(seed=args.seed, stress=stress)
