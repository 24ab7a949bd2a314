"""`ratouch world`: write a split in the TVL layout, a contact sheet, the material probe.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ratouch.cli.common import usage, world_cfg
from ratouch.files import atomic_path
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import check_writable, write_split
from ratouch.world.preview import contact_sheet
from ratouch.world.probe import ProbeConfig, format_probe, run_probe
from ratouch.world.sampler import TEST_SIZE, World
from ratouch.world.scarcity import ScarceRegime


def run(args: argparse.Namespace) -> int:
    if args.world_cmd == "probe":
        result = run_probe(WorldConfig(seed=args.seed),
                           ProbeConfig(n_train=args.n_train, n_test=args.n_test,
                                       workers=args.workers), progress=not args.json)
        print(json.dumps(result, indent=2) if args.json else format_probe(result))
        return 0
    cfg = world_cfg(args)
    if args.world_cmd == "build":
        regime = ScarceRegime(regime=args.regime, seed=args.seed, draw=args.draw)
        counts = write_split(cfg, args.out, args.split, args.n, workers=args.workers,
                             regime=regime)
        print(json.dumps({"out": str(args.out), "split": args.split, **counts}))
    else:  # preview
        out = Path(args.out)
        if out.suffix.lower() != ".png":
            raise usage(f"--out {out} must be a .png file")
        check_writable(out.parent)
        world = World(cfg)
        limit = TEST_SIZE if args.split == "test" else None
        idx = [args.start + k * args.stride for k in range(args.n)]
        if limit is not None:
            idx = [i % limit for i in idx]
        sheet = contact_sheet([world.sample(args.split, i) for i in idx], columns=args.columns)
        with atomic_path(out) as tmp:
            sheet.save(tmp, format="PNG")
        print(f"wrote {out} ({len(idx)} samples, {sheet.size[0]}x{sheet.size[1]})")
    return 0
