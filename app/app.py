"""RA-Touch Explorer app (for now: the world browser).

Browse the procedural visuo-tactile world sample by sample: visual image with its contact box,
tactile frame, tactile label, appearance-only description, and the stress knobs. The retrieval
views arrive with the model; the app holds no model logic of its own.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gradio as gr
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from ratouch.errors import RATouchError  # noqa: E402
from ratouch.world.config import StressConfig, WorldConfig  # noqa: E402
from ratouch.world.generator import TEST_SIZE, World  # noqa: E402
from ratouch.world.preview import draw_box  # noqa: E402


def show_sample(split: str, index: float, seed: float, scale: float, clutter: float,
                dominance: float, noise: float, blur: float, offset: float):
    """Render one sample with the chosen knobs (0 for scale/clutter means: natural)."""
    try:
        stress = StressConfig(
            object_scale=scale or None, clutter=int(clutter) if clutter >= 0 else None,
            background_dominance=dominance if dominance >= 0 else None,
            tactile_noise=noise if noise >= 0 else None,
            tactile_blur=blur if blur >= 0 else None, box_offset=offset)
        world = World(WorldConfig(seed=int(seed), stress=stress))
        s = world.sample(split, int(index) % TEST_SIZE if split == "test" else int(index))
    except RATouchError as e:
        raise gr.Error(str(e)) from e
    info = (f"**{s.class_name or 'close-up (structured)'}** · material `{s.material}` · "
            f"subset {s.subset}\n\n**Tactile label:** {s.caption}\n\n"
            f"**Appearance-only description:** {s.description}\n\n"
            f"Contact box {s.box} (ground truth {s.box_true}) · object scale "
            f"{s.object_scale:.2f} · sensor {s.sensor} · contact {s.contact}")
    visual = draw_box(s.visual, s.box).resize((384, 384))
    tactile = Image.fromarray(s.tactile).resize((288, 384))
    return visual, tactile, info


def build_demo() -> gr.Blocks:
    with gr.Blocks(title="RA-Touch Explorer — world") as demo:
        gr.Markdown("# RA-Touch Explorer — the procedural visuo-tactile world")
        with gr.Row():
            split = gr.Dropdown(["test", "train", "probe"], value="test", label="split")
            index = gr.Number(value=60, precision=0, label="index")
            seed = gr.Number(value=0, precision=0, label="world seed")
        with gr.Accordion("stress knobs (-1 / 0 = natural distribution)", open=False):
            with gr.Row():
                scale = gr.Slider(0, 1, value=0, step=0.05, label="object scale (0 = natural)")
                clutter = gr.Slider(-1, 12, value=-1, step=1, label="clutter")
                dominance = gr.Slider(-1, 1, value=-1, step=0.05, label="background dominance")
            with gr.Row():
                noise = gr.Slider(-1, 0.3, value=-1, step=0.01, label="tactile noise")
                blur = gr.Slider(-1, 6, value=-1, step=0.1, label="tactile blur")
                offset = gr.Slider(0, 3, value=0, step=0.1, label="contact-box offset")
        go = gr.Button("Show sample", variant="primary")
        with gr.Row():
            visual = gr.Image(label="visual + contact box", type="pil")
            tactile = gr.Image(label="tactile frame")
        info = gr.Markdown()
        inputs = [split, index, seed, scale, clutter, dominance, noise, blur, offset]
        go.click(show_sample, inputs, [visual, tactile, info])
        demo.load(show_sample, inputs, [visual, tactile, info])
    return demo


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=7860)
    args = p.parse_args(argv)
    build_demo().queue(default_concurrency_limit=2).launch(server_name=args.host,
                                                           server_port=args.port)


if __name__ == "__main__":
    main()
