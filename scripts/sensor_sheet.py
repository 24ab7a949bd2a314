"""Contact sheet of the world's tactile sensor families, to compare with real sensors by eye.

For each family (digit, gelsight, mini): a row of its units' backgrounds and a row of contact
frames of different materials (soft and hard, textured), each frame on a unit of the family;
the real DIGIT reference frames (`../shared/data/reference_tactile/*.png` relative to the
repository, when present) sit beside the digit rows.

    .venv/bin/python scripts/sensor_sheet.py --out sheet.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from ratouch.eval.sensors import real
from ratouch.world.config import WorldConfig
from ratouch.world.material import material
from ratouch.world.sampler import World
from ratouch.world.sensors import canonical, family_names
from ratouch.world.tactile import (
    UNITS_PER_FAMILY,
    family_sensors,
    plan_tactile,
    render_tactile,
)

MATERIALS = ("denim", "wool_knit", "oak", "glass", "sandpaper", "leather", "sponge", "corduroy")
REFERENCE_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "reference_tactile"


def family_frames(world: World, family: str, materials=MATERIALS, seed: int = 0
                  ) -> list[tuple[str, int, np.ndarray]]:
    """(material, sensor, frame) of one contact frame per material on the family's units."""
    units = list(family_sensors(family))
    out = []
    for i, name in enumerate(materials):
        plan = plan_tactile(np.random.default_rng([seed, i]), world.cfg, material(name),
                            sensor=units[i % len(units)])
        frame = render_tactile(plan, world.pyramid, world.cfg.tactile_hw,
                               world.sensor_background(plan.sensor))
        out.append((name, plan.sensor, frame))
    return out


def sensor_sheet(world: World | None = None, units: int = UNITS_PER_FAMILY,
                 materials=MATERIALS, scale: int = 2, reference_dir: Path | None = REFERENCE_DIR
                 ) -> Image.Image:
    """The contact sheet as a PIL image."""
    world = world or World(WorldConfig())
    h, w = (d * scale for d in world.cfg.tactile_hw)
    pad, text = 6, 14
    # per family the real frames the project can see: a background, then two presses
    refs = {}
    if reference_dir is not None:
        for family in family_names():
            found = real(family)
            if found is not None:
                refs[family] = ([found[1][0]], found[0][:2])
    n_real = 2 if refs else 0
    cols = max(units, len(materials)) + (1 + n_real if refs else 0)  # a gap, then real frames
    row_h = h + text + pad
    sheet = Image.new("RGB", (cols * (w + pad) + pad + 70, 2 * len(family_names()) * row_h + pad),
                      (245, 245, 245))
    draw = ImageDraw.Draw(sheet)
    y = pad
    for family in family_names():
        bgs = [(f"bg {k}", world.background_image(k)) for k in list(family_sensors(family))[:units]]
        frames = [(f"{m} ({k})", f) for m, k, f in family_frames(world, family, materials)]
        for caption, row in ((f"{family}\nunits", bgs), (f"{family}\ncontact", frames)):
            draw.text((4, y + h // 2 - 8), caption, fill=(0, 0, 0))
            x = 70
            for name, img in row:
                sheet.paste(Image.fromarray(img).resize((w, h), Image.NEAREST), (x, y))
                draw.text((x, y + h + 1), name, fill=(40, 40, 40))
                x += w + pad
            if family in refs:
                # the real no-contact frame beside the units, real presses beside the frames
                x = 70 + (max(units, len(materials)) + 1) * (w + pad)
                for im in refs[family][0 if row is bgs else 1]:
                    im = Image.fromarray(canonical(np.asarray(im))).resize((w, h), Image.BILINEAR)
                    sheet.paste(im, (x, y))
                    draw.text((x, y + h + 1), "real", fill=(160, 20, 20))
                    x += w + pad
            y += row_h
    return sheet


def main(argv=None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="sensor_sheet.png")
    ap.add_argument("--units", type=int, default=UNITS_PER_FAMILY,
                    help="backgrounds shown per family")
    ap.add_argument("--materials", default=",".join(MATERIALS),
                    help="comma-separated material names of the contact row")
    ap.add_argument("--scale", type=int, default=2)
    ap.add_argument("--no-reference", action="store_true",
                    help="leave out the real DIGIT reference frames")
    args = ap.parse_args(argv)
    sheet = sensor_sheet(units=args.units, materials=tuple(args.materials.split(",")),
                         scale=args.scale,
                         reference_dir=None if args.no_reference else REFERENCE_DIR)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(out)
    print(out)
    return out


if __name__ == "__main__":
    main()
