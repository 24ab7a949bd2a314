"""Stability where the methods fail: the world's test split under each stress knob.

For every knob (`ratouch.world.config.StressConfig`) the test split is rendered at a series of
values, encoded, and answered by every query mode (image / tactile / joint retrieval against
the corpus's text index) and by both generators (the no-retrieval baseline and RA-Touch). Each
sweep point reports

* retrieval, per mode: material precision@K and label-adjective overlap@K (the metrics of
  `ratouch.eval.retrieval`), and the top-K overlap |ids ∩ ids_ref| / K with the unperturbed
  answer for the same sample;
* generators, per system: mean offline-judge score (1-10), the share of descriptions identical
  to the unperturbed one, and the mean adjective Jaccard with it.

Break points: per knob and series, the first value (in sweep order, mildest first) at which the
quality falls below `drop` x its unperturbed value ("holds" if none does). The natural split is
also broken down by object-scale bin, and the retriever's joint queries are checked for collapse
with and without the stability loss (an "align"-only retriever trained into the cache against
the shipped "full" one).

Pairing. The world draws a knob's value from the sample's random stream only when the knob is
unset (None = the natural distribution); a fixed value skips that draw, so every later draw
(layout, colours, tactile pose, label adjectives) shifts and the sample becomes a different
scene of the same object class and material. To compare like with like, a knob that replaces a
per-sample draw (object_scale, clutter, background_dominance, tactile_noise, tactile_blur) is
compared with a *paired reference*: the same samples rendered with that knob fixed to each
sample's own natural value, which skips the same draw, so the reference and the stressed sample
differ only in the knob (the reference's values follow the natural distribution exactly).
box_offset > 0 adds a draw (the shift's direction): its reference is the split with a 1e-6
shift, which takes that draw and rounds to the unshifted box. clutter remains partly unpaired:
each distractor takes draws of its own, so a count other than the natural one still shifts the
later draws (contact box, lighting, tactile press, label); `paired_labels` (share of samples
whose label adjectives equal the reference's) shows how far each point is paired.
tactile_rotation and missing take no draw (0 / "none" are the natural values): their reference
is the natural split itself.

Missing tactile (`missing="tactile"`: the sensor gives a no-contact frame): the system is told
the modality is missing and falls back to image-only retrieval, as `RATouchPipeline.query` does,
so the tactile and joint modes answer with the image query; the generators still need a
tactile embedding and read the no-contact frame, RA-Touch with the image-only neighbours. The
point also reports, under `retrieval_no_fallback`, what the tactile and joint queries retrieve
from the no-contact frame when nothing falls back. `missing="visual"` (not in the default
sweep) is answered as it comes: the blank image is the image query, nothing falls back.

Modules: `sweeps` (knobs, values, samples), `scoring` (answering and scoring a point, break
points), `collapse`, `runner` (`run_stress`), `charts` (the figures) and `report` (console table,
markdown and files).
"""

from ratouch.eval.stress.charts import figures
from ratouch.eval.stress.collapse import collapse_report
from ratouch.eval.stress.report import format_markdown, format_table, write_report
from ratouch.eval.stress.runner import run_stress
from ratouch.eval.stress.scoring import SCALE_BINS, break_points
from ratouch.eval.stress.sweeps import (
    DEFAULT_N,
    KNOBS,
    PAIR_FIXED,
    PAPER_FAILURE,
    PER_SAMPLE,
    SWEEPS,
    build_sweeps,
    parse_values,
    stratified_indices,
)

__all__ = [
    "DEFAULT_N", "KNOBS", "PAIR_FIXED", "PAPER_FAILURE", "PER_SAMPLE", "SCALE_BINS", "SWEEPS",
    "break_points", "build_sweeps", "collapse_report", "figures", "format_markdown",
    "format_table", "parse_values", "run_stress", "stratified_indices", "write_report",
]
