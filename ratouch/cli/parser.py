"""Every `ratouch` command and its arguments, and which module of `ratouch.cli` runs it (the
`module` default that `main` dispatches on). Light on purpose: building the parser imports
nothing of the model side, so `ratouch --help` and usage errors stay fast.
"""

from __future__ import annotations

import argparse
import math

from ratouch.corpus.recaption import BACKENDS
from ratouch.encoders.factory import CHAIN_SETS, DEFAULT_ENCODER, DEFAULT_SETS, OTHER_SETS
from ratouch.eval.catalog import ARM_NAMES, EXPERIMENT_HELP, SYSTEMS
from ratouch.search.kinds import APPROXIMATE_KINDS, BENCH_KINDS, KINDS
from ratouch.search.modes import RETRIEVAL_SYSTEMS

DESCRIPTION = "The `ratouch` command line: a thin client of the library."


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit code 2), as the CLI promises."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


#: The largest magnitude a number typed on the command line may have (64-bit signed).
MAX_INT = 2**63 - 1


def _int(text: str) -> int:
    """A whole number within the 64-bit range (one-line errors naming the value)."""
    try:
        v = int(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from e
    if abs(v) > MAX_INT:
        raise argparse.ArgumentTypeError(f"{text!r} is beyond the 64-bit range")
    return v


def _nonneg_int(text: str) -> int:
    v = _int(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 0")
    return v


def _pos_int(text: str) -> int:
    v = _int(text)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return v


def _arm_list(text: str) -> tuple[str, ...]:
    """A comma-separated list of `ARM_NAMES` (empty: none)."""
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    bad = [n for n in names if n not in ARM_NAMES]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown arm(s) {bad}: choose from "
                                         f"{', '.join(ARM_NAMES)}")
    return names


def _number(text: str) -> float:
    """A finite number within the 64-bit range (inf, NaN and 1e308 are refused by name)."""
    try:
        v = float(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from e
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    if abs(v) > MAX_INT:
        raise argparse.ArgumentTypeError(f"{text!r} is beyond the 64-bit range")
    return v


def _add_world(sub) -> None:
    world = sub.add_parser("world", help="the procedural visuo-tactile world")
    world.set_defaults(module="world")
    wsub = world.add_subparsers(dest="world_cmd", required=True)

    b = wsub.add_parser("build", help="write a split in the TVL data set layout")
    b.add_argument("--out", required=True, help="data set root folder")
    b.add_argument("--split", choices=("train", "test"), default="train")
    b.add_argument("--n", type=_pos_int, default=None,
                   help="number of pairs (train default 20000; test is always 402)")
    b.add_argument("--seed", type=_nonneg_int, default=0)
    b.add_argument("--workers", type=_pos_int, default=2)
    b.add_argument("--regime", choices=("scarce", "full"), default="scarce",
                   help="train split: the scarce-touch regime's pairs (14 materials keep 8 "
                        "pairs each; see docs/premise.md) or every pair")
    b.add_argument("--draw", type=_nonneg_int, default=0,
                   help="which few pairs of the scarce materials are kept")
    _add_stress(b)

    p = wsub.add_parser("preview", help="a contact sheet PNG a person can look at")
    p.add_argument("--out", required=True, help="PNG file to write")
    p.add_argument("--split", choices=("train", "test"), default="test")
    p.add_argument("--n", type=_pos_int, default=24)
    p.add_argument("--start", type=_nonneg_int, default=0, help="first sample index")
    p.add_argument("--stride", type=_pos_int, default=17, help="index step between samples")
    p.add_argument("--seed", type=_nonneg_int, default=0)
    p.add_argument("--columns", type=_pos_int, default=4)
    _add_stress(p)

    pr = wsub.add_parser("probe", help="material probe: visual vs tactile vs both")
    pr.add_argument("--n-train", type=_pos_int, default=2400)
    pr.add_argument("--n-test", type=_pos_int, default=800)
    pr.add_argument("--seed", type=_nonneg_int, default=0)
    pr.add_argument("--workers", type=_pos_int, default=2)
    pr.add_argument("--json", action="store_true", help="print JSON")


def _add_lm(p: argparse.ArgumentParser) -> None:
    p.add_argument("--lm", default=None, metavar="NAME",
                   help="the generators adapted from this pretrained language model "
                        "(`ratouch train generator --lm NAME`) instead of the small decoder's")


def _add_stress(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("stress knobs")
    g.add_argument("--object-scale", type=_number, help="object side / frame side, 0.1..1")
    g.add_argument("--clutter", type=int, help="number of distractors")
    g.add_argument("--background-dominance", type=_number, help="0..1")
    g.add_argument("--tactile-noise", type=_number, help="sensor noise std, 0..0.3")
    g.add_argument("--tactile-blur", type=_number, help="gel blur sigma, pixels")
    g.add_argument("--tactile-rotation", type=_number, help="texture rotation, degrees")
    g.add_argument("--box-offset", type=_number, default=0.0, help="box shift / box side")
    g.add_argument("--missing", choices=("none", "visual", "tactile"), default="none")
    g.add_argument("--no-contact", type=_number, default=0.0, help="no-contact frame rate")


def _add_corpus(sub) -> None:
    corpus = sub.add_parser("corpus", help="ImageNet-T, the tactile-recaptioned corpus")
    corpus.set_defaults(module="corpus")
    csub = corpus.add_subparsers(dest="corpus_cmd", required=True)
    b = csub.add_parser("build", help="recaption and sample a corpus")
    b.add_argument("--size", default="10k", help="10k, 50k, 100k, 150k or a count")
    b.add_argument("--out", required=True,
                   help="corpus folder; one holding this corpus (a killed run's) is finished, "
                        "not rebuilt")
    b.add_argument("--seed", type=_nonneg_int, default=0)
    b.add_argument("--captioner", choices=BACKENDS, default="offline",
                   help="smollm2: SmolLM2-135M-Instruct on this machine (local engine only)")
    b.add_argument("--endpoint", help="OpenAI-compatible base URL for --captioner llm "
                                      "(key from $RATOUCH_LLM_API_KEY)")
    b.add_argument("--model", default="gpt-4o-mini")
    b.add_argument("--from-list", help="CSV or Parquet of (image path, class, caption), or a "
                                       "folder FOLDER/<class>/<image>, for a real corpus")
    b.add_argument("--encoder", default=DEFAULT_ENCODER, help="encoder to embed with")
    b.add_argument("--index", choices=KINDS, default="flat",
                   help="with --engine ray, ivfflat/ivfpq are built from the shards on disk")
    b.add_argument("--no-embed", action="store_true", help="only recaption and sample")
    b.add_argument("--overwrite", action="store_true",
                   help="replace the corpus --out holds (another size, seed, source...)")
    b.add_argument("--reindex", action="store_true",
                   help="build the encoder's --index again (one refused as corrupt)")
    b.add_argument("--workers", type=_pos_int, default=2,
                   help="render processes (local) or embedding actors (ray)")
    b.add_argument("--engine", choices=("local", "ray"), default="local",
                   help="local: one process; ray: a Ray Data pipeline, resumable shards")
    b.add_argument("--address", default=None, help="Ray cluster address (default: "
                                                   "$RAY_ADDRESS, else a local Ray)")
    b.add_argument("--num-cpus", type=_pos_int, default=None, help="CPUs of a local Ray")
    b.add_argument("--batch-size", type=_pos_int, default=250, help="entries per Ray batch")
    b.add_argument("--shard-size", type=_pos_int, default=1000, help="entries per shard")
    b.add_argument("--llm-concurrency", type=_pos_int, default=8,
                   help="LLM requests in flight at once (ray)")
    b.add_argument("--llm-rate", type=_number, default=50.0,
                   help="LLM requests per second, 0 for no limit (ray)")


    rc = csub.add_parser("recaption", help="recaption your own images offline: a folder in "
                                           "ImageNet's layout (FOLDER/<class>/<image>) into "
                                           "an ImageNet-T corpus folder `corpus build` embeds")
    rc.add_argument("--images", required=True, help="FOLDER/<class>/<image>: the subfolder "
                                                    "names are the class names")
    rc.add_argument("--out", required=True, help="corpus folder to write (must hold none)")
    rc.add_argument("--recaptioner", choices=("smollm2", "offline"), default="smollm2",
                    help="smollm2: SmolLM2-135M-Instruct constrained to the TVL adjectives; "
                         "offline: the lexicon recaptioner")


def _stage2_parser(tsub, name: str, help: str) -> argparse.ArgumentParser:
    """`ratouch train NAME`: a generator trained as RA-Touch's stage 2 again from the shipped
    stage 1 (the reader, the text system's), with the arguments they share."""
    p = tsub.add_parser(name, help=help)
    p.add_argument("--encoder", default=DEFAULT_ENCODER)
    p.add_argument("--seed", type=_nonneg_int, default=0)
    p.add_argument("--steps", type=_pos_int, default=None,
                   help="stage-2 steps (default: RA-Touch's, 600)")
    p.add_argument("--out", default=None,
                   help=f"checkpoint folder (default: assets/generator/ENCODER/{name})")
    return p


def _add_train(sub) -> None:
    train = sub.add_parser("train", help="train the default models")
    train.set_defaults(module="train")
    tsub = train.add_subparsers(dest="train_cmd", required=True)
    e = tsub.add_parser("encoders", help="train the default vision/tactile/text encoders")
    e.add_argument("--model", action="append", choices=(*DEFAULT_SETS, "debug"),
                   help="encoder(s) to train (repeatable; default: tiny, s and b)")
    e.add_argument("--out", default=None, help="folder for the weights (default: assets/encoders)")
    e.add_argument("--seed", type=_nonneg_int, default=0)
    e.add_argument("--steps", type=_pos_int, default=None, help="override the step count")
    e.add_argument("--n-pairs", type=_pos_int, default=12_000)
    e.add_argument("--n-corpus", type=_pos_int, default=8_000)
    e.add_argument("--threads", type=_pos_int, default=2, help="torch threads for training")
    e.add_argument("--device", default="cpu",
                   help="where the training steps run: cpu (default) or cuda[:N] where a GPU is "
                        "seen (the data is rendered on the CPU either way)")
    r = tsub.add_parser("retriever", help="train the Tactile-Guided Retriever (then frozen)")
    r.add_argument("--encoder", default=DEFAULT_ENCODER)
    r.add_argument("--seed", type=_nonneg_int, default=0)
    r.add_argument("--strategy", choices=("align", "align_mse", "align_div_nce", "full"),
                   default="full", help="loss strategy (the paper's Fig. 5 compares them)")
    r.add_argument("--paper-exact", action="store_true",
                   help="no residual around the cross-attention (eq. 2 as printed)")
    r.add_argument("--epochs", type=_pos_int, default=None)
    g = tsub.add_parser("generator", help="train the baseline and RA-Touch generators")
    g.add_argument("--encoder", default=DEFAULT_ENCODER)
    g.add_argument("--seed", type=_nonneg_int, default=0)
    g.add_argument("--draw", type=_nonneg_int, default=0,
                   help="which few pairs of the scarce materials the paired split keeps")
    g.add_argument("--out", default=None,
                   help="folder for baseline/ and ra/ (default: the shipped assets)")
    g.add_argument("--stage0-steps", type=_pos_int, default=None,
                   help="language-prior steps (used only when assets/generator/ENC/prior "
                        "is missing)")
    g.add_argument("--stage1-steps", type=_pos_int, default=None)
    g.add_argument("--stage2-steps", type=_pos_int, default=None)
    g.add_argument("--lm", default=None, metavar="NAME|FOLDER",
                   help="adapt a pretrained language model instead of the small decoder: "
                        "smollm2-135m (SmolLM2-135M-Instruct from its wheel) or a local "
                        "HF-format LLaMA folder; the visual prompt and LoRA, saved to "
                        "assets/generator/ENC/NAME/ (a folder's NAME is its folder name)")
    tr = tsub.add_parser("trust", help="calibrate the trust signals (novelty, no contact) on "
                                       "the world's validation renders")
    tr.add_argument("--encoder", default=DEFAULT_ENCODER)
    tr.add_argument("--seed", type=_nonneg_int, default=0)
    tr.add_argument("--false-alarm", type=_number, default=0.02,
                    help="share of in-distribution validation inputs each signal may flag")
    tr.add_argument("--out", default=None,
                    help="calibration JSON (default: assets/trust/ENCODER.json)")
    tr.add_argument("--alone-band", action="store_true",
                    help="only (re)set the no-background 'uncertain' band per sensor family "
                         "on fresh blank renders, in the stored calibration (its other "
                         "figures unchanged)")
    tr.add_argument("--unfamiliar", action="store_true",
                    help="only (re)fit the colour-blind contact model that reads a frame "
                         "alone from a sensor unlike every rendered unit, in the stored "
                         "calibration (its other figures unchanged)")
    gt = tsub.add_parser("gate", help="fit the touch gate (how far touch steers the gated "
                                      "query) on probe renders with clean, mismatched, blank "
                                      "and noisy touch")
    gt.add_argument("--encoder", default=DEFAULT_ENCODER)
    gt.add_argument("--seed", type=_nonneg_int, default=0)
    gt.add_argument("--n", type=_pos_int, default=1200, help="probe pairs (half fit, half measure)")
    gt.add_argument("--out", default=None,
                    help="gate JSON (default: assets/gate/ENCODER.json)")
    pm = tsub.add_parser("press-map", help="fit the press map (the adapted tactile query: "
                                           "everyday presses brought back to their material's "
                                           "captions) on renders of everyday and world presses")
    pm.add_argument("--encoder", default=DEFAULT_ENCODER)
    pm.add_argument("--seed", type=_nonneg_int, default=0)
    pm.add_argument("--fit", type=_pos_int, default=40,
                    help="everyday presses per family and kind fitted on")
    pm.add_argument("--world", type=_pos_int, default=600,
                    help="the world's training renders fitted on")
    pm.add_argument("--balls", type=_nonneg_int, default=0,
                    help="rigid-ball renders per family fitted on with the world's presses "
                         "(default 0, the shipped recipe; docs/geometry.md: 40 was tried "
                         "and not shipped)")
    pm.add_argument("--eval", type=_pos_int, default=12,
                    help="fresh everyday presses per family and kind the report reads")
    pm.add_argument("--world-eval", type=_pos_int, default=300,
                    help="the world's validation renders the report reads")
    pm.add_argument("--balls-eval", type=_pos_int, default=20,
                    help="fresh rigid balls per family the report reads")
    pm.add_argument("--steps", type=_pos_int, default=600)
    pm.add_argument("--router-balls", type=_pos_int, default=40,
                    help="rigid-ball renders per family the regime router is fitted on")
    pm.add_argument("--router-only", action="store_true",
                    help="fit only the regime router (which regime a frame read alone is a "
                         "press of) onto the shipped map; its weights unchanged")
    pm.add_argument("--out", default=None,
                    help="press map file (default: assets/press_map/ENCODER.npz)")
    rd = _stage2_parser(tsub, "reader", "train the gated system's generator (the reader): "
                                        "RA-Touch's stage 2 on the gated query's neighbours, "
                                        "half the samples with touch degraded")
    rd.add_argument("--arm", choices=("integrator", "text"), default=None,
                    help="how the reader hands its neighbours to the decoder: a Texture-Aware "
                         "Integrator or their captions in the prompt (default: the shipped "
                         "reader's form)")
    _stage2_parser(tsub, "text", "train the text system's generator: RA-Touch's stage 2 with "
                                 "the joint query's neighbours' captions written into the "
                                 "prompt (no Texture-Aware Integrator)")
    ge = tsub.add_parser("geometry", help="fit each sensor family's colour-to-gradient lookup "
                                          "(Taxim's real ball presses; the DIGIT shader's "
                                          "renders) and its contact floors on blank renders")
    ge.add_argument("--seed", type=_nonneg_int, default=0)
    ge.add_argument("--samples", type=_pos_int, default=120_000,
                    help="pixels each family's lookup is fitted on")
    ge.add_argument("--pairs", type=_pos_int, default=300,
                    help="drifted blank render pairs each family's contact floors are set on")
    ge.add_argument("--firmness-per-kind", type=_pos_int, default=60,
                    help="renders per kind of everyday press each family's firmness model "
                         "is fitted on")
    ge.add_argument("--firmness-world", type=_nonneg_int, default=300,
                    help="the world's renders with contact a family the firmness model also "
                         "reads (0: everyday presses only)")
    ge.add_argument("--firmness-only", action="store_true",
                    help="keep the calibration's lookups and floors; fit only the firmness "
                         "models (read from --out or the shipped file)")
    ge.add_argument("--unfamiliar-floors", action="store_true",
                    help="keep the calibration's lookups, floors and firmness models; set only "
                         "the floors a sensor unlike every rendered unit is held to, on "
                         "--pairs recoloured blank pairs a family (read from --out or the "
                         "shipped file)")
    ge.add_argument("--floors-only", action="store_true",
                    help="keep the calibration's lookups, unfamiliar-sensor floors and "
                         "firmness models; set only each family's floors, threshold and the "
                         "noise they are set at, on --pairs drifted blank pairs a family "
                         "(read from --out or the shipped file)")
    ge.add_argument("--out", default=None,
                    help="calibration JSON (default: assets/geometry/lookups.json)")
    cc = tsub.add_parser("cascade", help="calibrate the encoder cascade (smallest confident "
                                         "encoder answers) on the world's validation renders")
    cc.add_argument("--encoders", default=",".join(CHAIN_SETS),
                    help="encoder sets, smallest first (each needs its retriever and generators)")
    cc.add_argument("--seed", type=_nonneg_int, default=0)
    cc.add_argument("--n", type=_pos_int, default=1000, help="validation pairs")
    cc.add_argument("--out", default=None,
                    help="calibration JSON (default: assets/cascade/ENC1+ENC2.json)")
    a = tsub.add_parser("all", help="encoders, corpus embeddings, retriever, language prior, "
                                    "generators and trust calibration, in order")
    a.add_argument("--seed", type=_nonneg_int, default=0)


def _add_eval(sub) -> None:
    ev = sub.add_parser("eval", help="evaluations that print measured figures")
    esub = ev.add_subparsers(dest="eval_cmd", required=True)
    r = esub.add_parser("retrieval", help="material precision@K and adjective overlap@K")
    r.add_argument("--corpus", default=None, help="corpus folder (default: the cached 10k)")
    r.add_argument("--encoder", default=DEFAULT_ENCODER)
    r.add_argument("--index", choices=KINDS, default="flat")
    r.add_argument("--seed", type=_nonneg_int, default=0, help="world seed of the test split")
    r.add_argument("--json", action="store_true")
    t = esub.add_parser("tvl", help="TVL benchmark protocol on the world's test split: "
                                    "generate, judge, write a TVL-format results file")
    t.add_argument("--system", choices=SYSTEMS, required=True)
    t.add_argument("--out", required=True, help="results JSON to write (TVL format + scores)")
    t.add_argument("--encoder", default=DEFAULT_ENCODER)
    t.add_argument("--k", type=_pos_int, default=5, help="neighbours RA-Touch reads")
    t.add_argument("--retrieval", choices=tuple(RETRIEVAL_SYSTEMS), default="paper",
                   help="RA-Touch's retrieval system (the test split's frames all look like "
                        "rendered units, so 'fallback' answers there as 'paper' does)")
    _add_lm(t)
    t.add_argument("--seed", type=_nonneg_int, default=0, help="world seed of the test split")
    t.add_argument("--validation", action="store_true",
                   help="judge 402 validation pairs of the world's train split (from index "
                        "4,000,000, used by no training) instead of the test split: for "
                        "choosing a setting without looking at the test split")
    _add_stress(t)
    _add_judge_options(t)
    t.add_argument("--json", action="store_true")
    st = esub.add_parser("stress", help="quality and stability of retrieval and generation "
                                        "under each stress knob, break points, collapse check")
    st.add_argument("--encoder", default=DEFAULT_ENCODER)
    st.add_argument("--k", type=_pos_int, default=5, help="neighbours per query (P@K, overlap@K)")
    st.add_argument("--n", type=_pos_int, default=None,
                    help="test samples, stratified over structured/wild (default 200; 402 = all)")
    st.add_argument("--knobs", default=None,
                    help="comma-separated knobs (default all: object_scale, clutter, "
                         "background_dominance, tactile_noise, tactile_blur, tactile_rotation, "
                         "box_offset, missing, paper_failure)")
    st.add_argument("--values", action="append", metavar="KNOB=V1,V2",
                    help="other sweep values for a knob (repeatable)")
    st.add_argument("--drop", type=_number, default=0.8,
                    help="break point: quality below this fraction of the unperturbed value")
    st.add_argument("--no-collapse", action="store_true",
                    help="skip the collapse diagnostic (it trains an align-only retriever once)")
    st.add_argument("--collapse-epochs", type=_pos_int, default=12,
                    help="epochs of the align-only retriever (the shipped one had 12)")
    st.add_argument("--seed", type=_nonneg_int, default=0, help="world seed of the test split")
    st.add_argument("--out", default="reports/stress",
                    help="report folder (the committed full sweep is docs/stress: "
                         "`--out docs/stress` regenerates it in place)")
    st.add_argument("--json", action="store_true", help="print the result as JSON")

    for name, about in [*EXPERIMENT_HELP.items(),
                        ("all", "every paper experiment; regenerates docs/results.md")]:
        e = esub.add_parser(name, help=about)
        e.set_defaults(module="experiments")
        e.add_argument("--out", default="docs" if name == "all" else "reports",
                       help="folder for the markdown and figures (figures/ inside it)")
        e.add_argument("--steps", type=_pos_int, default=300,
                       help="stage-2 training steps of every generator variant")
        e.add_argument("--workers", type=_pos_int, default=2,
                       help="variants trained in parallel (one thread each)")
        e.add_argument("--encoder", default=DEFAULT_ENCODER)
        e.add_argument("--seed", type=_nonneg_int, default=0)
    tt = esub.add_parser("ttest", help="paired t-test between two scored results files (B - A)")
    tt.add_argument("a", help="results file A (e.g. the baseline)")
    tt.add_argument("b", help="results file B (e.g. RA-Touch)")
    tt.add_argument("--json", action="store_true")
    c = esub.add_parser("controls", help="does RA-Touch read its neighbours? shuffled "
                                         "neighbours, zeroed integrator, copy and oracle ceilings")
    c.add_argument("--encoder", default=DEFAULT_ENCODER)
    c.add_argument("--k", type=_pos_int, default=5, help="neighbours RA-Touch reads")
    c.add_argument("--shuffles", type=_pos_int, default=3, help="neighbour shuffles (seeds)")
    _add_lm(c)
    c.add_argument("--seed", type=_nonneg_int, default=0, help="seed of the shuffles and CIs")
    c.add_argument("--json", action="store_true")
    pr = esub.add_parser("premise", help="the paper's premise: baseline against RA-Touch on "
                                         "seen and scarce materials, over runs, with controls "
                                         "and the pre-registered verdict (docs/premise.md)")
    pr.add_argument("--encoder", default=DEFAULT_ENCODER)
    pr.add_argument("--runs", type=_pos_int, default=3,
                    help="runs (run r: training seed r, draw r; run 0 is the shipped weights, "
                         "the others train into the cache on first use, ~8 min each)")
    pr.add_argument("--n", type=_pos_int, default=500, help="held-out pairs per group")
    pr.add_argument("--k", type=_pos_int, default=5, help="neighbours RA-Touch reads")
    pr.add_argument("--no-arm", action="store_true",
                    help="leave out the second-stage arms (they train on first use)")
    pr.add_argument("--arms", type=_arm_list, default=",".join(ARM_NAMES),
                    help="comma-separated arms judged beside RA-Touch: tokens (neighbour "
                         "tokens), text (the neighbours' captions written into the prompt)")
    _add_lm(pr)
    pr.add_argument("--why", action="store_true",
                    help="instead: evidence for why the shipped generator does (not) read its "
                         "neighbours, on its training pairs (F1 of copying them, the "
                         "integrator's gradient with own vs shuffled neighbours, losses)")
    pr.add_argument("--json", action="store_true")
    ph = esub.add_parser("photos", help="the visible real photos (scikit-image's PD/CC0 ones, "
                                        "the real DIGIT frames): what the pipeline makes of "
                                        "each, for looking (no thresholds are set on them)")
    ph.add_argument("--encoder", default=DEFAULT_ENCODER)
    ph.add_argument("--k", type=_pos_int, default=5, help="neighbours per photo")
    ph.add_argument("--pairs", action="store_true",
                    help="instead: each photo with a real press (Taxim's, the DIGIT's) against "
                         "its background: RA-Touch with every retrieval system, the baseline, "
                         "and a copy of each mode's top-1 caption")
    ph.add_argument("--json", action="store_true")
    fa = esub.add_parser("families", help="per tactile sensor family, on validation renders: "
                                          "material probe, joint P@5 and contact miss / false "
                                          "alarm, without and with the sensor's background")
    fa.add_argument("--encoder", default=DEFAULT_ENCODER)
    fa.add_argument("--n", type=_pos_int, default=600, help="validation renders")
    fa.add_argument("--seed", type=_nonneg_int, default=0, help="world seed")
    fa.add_argument("--json", action="store_true")
    fr = esub.add_parser("frames", help="real tactile frames read for what they are: per frame "
                                        "its sensor family, contact reading, touch-only "
                                        "reading and the tactile query's neighbours")
    fr.add_argument("folder", nargs="?", help="a folder of your own sensor frames (png, jpg, "
                                              "...); omit with --real")
    fr.add_argument("--background", help="the sensor's no-contact frame, read against every "
                                         "frame of the folder")
    fr.add_argument("--real", action="store_true",
                    help="instead: the real frames the project can see (Taxim's 72 presses "
                         "and 2 backgrounds, the reference DIGIT frames)")
    fr.add_argument("--alone", action="store_true",
                    help="with --real: also read each of Taxim's presses without its "
                         "background (the contact model alone)")
    fr.add_argument("--encoder", default=DEFAULT_ENCODER)
    fr.add_argument("--corpus", default=None, help="a built corpus (default: the embedded one)")
    fr.add_argument("--k", type=_pos_int, default=5, help="neighbours per frame")
    fr.add_argument("--sheet", default=None,
                    help="also write a PNG: each frame beside its height map (frames read "
                         "against a background)")
    fr.add_argument("--json", action="store_true")
    se = esub.add_parser("sensors", help="rendered sensor frames against real ones in numbers "
                                         "(mean and spread of frame - background, spatial "
                                         "frequencies, contact area), per family")
    se.add_argument("--n", type=_pos_int, default=60, help="renders per family")
    se.add_argument("--json", action="store_true")
    pe = esub.add_parser("presses", help="contact on renders of everyday presses (flat faces, "
                                         "fabrics, foam, tape, wire, an edge, a small cap) per "
                                         "family, with and without a drifted background")
    pe.add_argument("--encoder", default=DEFAULT_ENCODER)
    pe.add_argument("--n", type=_pos_int, default=10, help="presses per family and kind")
    pe.add_argument("--blanks", type=_pos_int, default=40, help="blank pairs per family")
    pe.add_argument("--seed", type=_nonneg_int, default=1)
    pe.add_argument("--readings", type=_nonneg_int, default=0, metavar="N",
                    help="also read N presses per family and kind through the whole pipeline "
                         "by touch alone, with and without the background: hard against "
                         "soft, the judge against the material's words, distinct readings")
    pe.add_argument("--probe", type=_nonneg_int, default=0, metavar="N",
                    help="also probe N presses per family and kind: material and soft against "
                         "hard from the tactile embedding (with and without the background), "
                         "the press's shape, and both")
    pe.add_argument("--world", type=_nonneg_int, default=0, metavar="N",
                    help="also read the world's first N test presses and the same samples "
                         "without contact, alone and against their background: how many "
                         "land in each contact state, per family")
    pe.add_argument("--cross-unit", type=_nonneg_int, default=0, metavar="N",
                    help="also read N blank frames per family against another unit's "
                         "background (the wrong unit's no-contact frame): how many land in "
                         "each contact state")
    pe.add_argument("--landscape", action="store_true",
                    help="render the presses, blank pairs and cross-unit pairs landscape "
                         "(96 x 128) instead of portrait (128 x 96)")
    pe.add_argument("--json", action="store_true")
    rp = esub.add_parser("recaption", help="recaptioners against the world's own adjectives "
                                           "on corpus entries: adjective F1 and offline judge, "
                                           "with bootstrap 95 %% CIs, and ms per caption")
    rp.add_argument("--n", type=_pos_int, default=100, help="corpus entries (stratified)")
    rp.add_argument("--recaptioners", default="smollm2,offline",
                    help="comma-separated: smollm2, smollm2-greedy, offline")
    rp.add_argument("--seed", type=_nonneg_int, default=0, help="world seed of the corpus")
    rp.add_argument("--json", action="store_true")
    for p in (r, t, st, tt, c, pr, ph, fa, fr, se, pe, rp):
        p.set_defaults(module="eval")


def _add_judge_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--judge", choices=("offline", "llm"), default="offline")
    p.add_argument("--endpoint", help="OpenAI-compatible base URL for --judge llm "
                                      "(default $RATOUCH_JUDGE_ENDPOINT)")
    p.add_argument("--model", help="model for --judge llm (default $RATOUCH_JUDGE_MODEL or gpt-4)")
    p.add_argument("--api-key-env", default="RATOUCH_JUDGE_API_KEY",
                   help="environment variable holding the API key")


def _add_judge(sub) -> None:
    j = sub.add_parser("judge", help="score TVL-format results with the offline or LLM judge")
    j.set_defaults(module="judge")
    j.add_argument("file", nargs="*", help="TVL-format JSON list (label, generated response, ...); "
                                           "one system per file; several with --compare")
    j.add_argument("--out", help="scored JSON to write (the input plus offline_score/llm_score)")
    j.add_argument("--explain", action="store_true",
                   help="print, per answer, the words matched, clashed or ignored and their weights")
    j.add_argument("--compare", action="store_true",
                   help="agreement of the offline judge with the LLM judge (--endpoint) on FILE(s)")
    _add_judge_options(j)
    j.add_argument("--validate", action="store_true",
                   help="the offline judge's agreement with GPT-4 on held-out samples, on a "
                        "held-out system (leave one out) and under style shifts")
    j.add_argument("--length-effect", action="store_true",
                   help="a material oracle's score on the world's test split with 2/3/4/5 "
                        "adjectives (the judge's length effect)")
    j.add_argument("--fit", action="store_true",
                   help="refit the offline judge's calibration on the FIT part and write it")
    j.add_argument("--json", action="store_true", help="print JSON")


def _box(text: str) -> tuple[int, int, int, int]:
    parts = text.split(",")
    if len(parts) != 4:
        raise argparse.ArgumentTypeError(f"{text!r} must have 4 numbers: x0,y0,x1,y1")
    try:
        values = [_number(v) for v in parts]
    except argparse.ArgumentTypeError as e:
        raise argparse.ArgumentTypeError(f"box {text!r}: {e}") from e
    x0, y0, x1, y1 = (int(round(v)) for v in values)
    return x0, y0, x1, y1


def _id_list(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of "
                                         f"corpus ids") from e


def _add_query(sub) -> None:
    q = sub.add_parser("query", help="one RA-Touch query: neighbours, description, PCA, timings")
    q.set_defaults(module="query")
    q.add_argument("--vision", required=True, help="visual image file")
    q.add_argument("--tactile", default=None, help="tactile image file (optional)")
    q.add_argument("--background", default=None,
                   help="the tactile sensor's no-contact frame (optional; same size as the "
                        "tactile image): the frame is read against it, and the no-contact "
                        "check uses it")
    q.add_argument("--box", type=_box, default=None, help="contact box x0,y0,x1,y1 in pixels")
    q.add_argument("--k", type=_pos_int, default=5,
                   help="neighbours per query mode (at most the app's largest K, "
                        "serve.request.MAX_K)")
    q.add_argument("--label", default=None, help="ground-truth caption, if known (for the PCA)")
    q.add_argument("--retrieval", choices=tuple(RETRIEVAL_SYSTEMS), default=None,
                   help="RA-Touch's retrieval system: 'paper' (the joint query), 'gated' "
                        "(touch weighed by how far it can be trusted), 'text' (the neighbours' "
                        "captions in the prompt) or 'fallback' (the paper's, answering from "
                        "vision for a sensor unlike every rendered unit); default: the shipped "
                        "choice, 'fallback'")
    q.add_argument("--encoder", default=DEFAULT_ENCODER,
                   help="encoder set (default-tiny, default-s, default-b where trained), or "
                        "'cascade': the smallest confident one answers")
    q.add_argument("--corpus", default=None, help="corpus folder (default: the cached 10k)")
    q.add_argument("--index", choices=KINDS, default="flat",
                   help="the corpus's index kind to search (a large corpus built with "
                        "--index ivfflat|ivfpq loads that index memory-mapped)")
    q.add_argument("--json", action="store_true", help="print JSON (the default output)")
    q.add_argument("--drop", type=_id_list, default=None, metavar="IDS",
                   help="comma-separated corpus ids: regenerate the RA-Touch description "
                        "without these joint neighbours (printed under 'regenerated')")
    q.add_argument("--neighbours-from", default=None, metavar="FILE",
                   help="regenerate the RA-Touch description with other neighbours: a JSON "
                        "file holding another query's output (its joint neighbours are used) "
                        "or a list of corpus ids")


def _add_bench(sub) -> None:
    bench = sub.add_parser("bench", help="benchmarks that print measured figures")
    bench.set_defaults(module="bench")
    bsub = bench.add_subparsers(dest="bench_cmd", required=True)
    r = bsub.add_parser("retrieval", help="index latency / recall against the upstream method")
    r.add_argument("--n", type=_pos_int, default=150_000)
    r.add_argument("--dim", type=_pos_int, default=768)
    r.add_argument("--queries", type=_pos_int, default=200)
    r.add_argument("--scale", type=_nonneg_int, default=0,
                   help="also build/load/query an index of this many vectors (e.g. 1000000)")
    r.add_argument("--corpus", default=None,
                   help="instead of synthetic vectors: a built corpus's real embeddings, with "
                        "--queries of its entries held out as queries")
    r.add_argument("--encoder", default=DEFAULT_ENCODER, help="with --corpus: whose embeddings")
    r.add_argument("--key", choices=("image", "text", "both"), default="both",
                   help="with --corpus: which key's embeddings are indexed")
    r.add_argument("--kinds", default=",".join(APPROXIMATE_KINDS),
                   help="with --corpus: index kinds")
    r.add_argument("--json", action="store_true")
    to = bsub.add_parser("tradeoff", help="latency against quality over index, corpus size, "
                                          "K and encoder; one chart with the frontier")
    to.add_argument("--out", default="docs", help="writes figures/tradeoff.* inside it")
    to.add_argument("--n", type=_pos_int, default=30, help="timed queries per point")
    to.add_argument("--sizes", default="1000,2500,10000", help="corpus subset sizes")
    to.add_argument("--ks", default="1,5,10", help="values of K")
    to.add_argument("--indexes", default=",".join(BENCH_KINDS))
    to.add_argument("--encoders", default=",".join(OTHER_SETS),
                    help="other encoders, retrieval-only points ('' for none); a shipped "
                         "model (default-b, default-s+smollm2-135m) is a whole-answer point")
    to.add_argument("--json", action="store_true")
    qb = bsub.add_parser("query", help="latency of the whole RA-Touch query, cold and warm")
    qb.add_argument("--encoder", default=DEFAULT_ENCODER)
    qb.add_argument("--corpus", default=None)
    qb.add_argument("--n", type=_pos_int, default=60)
    qb.add_argument("--json", action="store_true")
    cb = bsub.add_parser("corpus", help="corpus build throughput per stage and peak memory, "
                                        "single process or on Ray")
    cb.add_argument("--engine", choices=("local", "ray"), default="ray")
    cb.add_argument("--n", type=_pos_int, default=2000)
    cb.add_argument("--workers", type=_pos_int, default=2,
                    help="render processes (local) or embedding actors (ray)")
    cb.add_argument("--encoder", default=DEFAULT_ENCODER)
    cb.add_argument("--json", action="store_true")
    up = bsub.add_parser("upload", help="a huge tactile upload: its latency, where the time "
                                        "goes, and the delay of a normal query beside it")
    up.add_argument("--encoder", default=DEFAULT_ENCODER)
    up.add_argument("--corpus", default=None)
    up.add_argument("--side", type=_pos_int, default=6000, help="side of the square PNG")
    up.add_argument("--repeats", type=_pos_int, default=3)
    mem = bsub.add_parser("memory", help="peak memory of a huge upload per image mode "
                                         "(16-bit, 1-bit, 8-bit, palette, CMYK, float) through "
                                         "the query's decode path, and of many at once")
    mem.add_argument("--side", type=_pos_int, default=7000, help="side of the square image")
    mem.add_argument("--burst", type=_pos_int, default=16, help="16-bit uploads at once")
    mem.add_argument("--modes", default="I;16,1,L,P,RGB,CMYK,F", help="PIL modes measured")
    mem.add_argument("--box-side", type=_pos_int, default=512, help="the contact box's side")
    mem.add_argument("--json", action="store_true", help="print JSON")
    tw = bsub.add_parser("towers", help="vision towers (the render CNN and every registered "
                                        "visual prior, "
                                        "at several input sizes): material probe and P@5 "
                                        "against single-crop latency on validation renders; "
                                        "one chart and the chosen tower")
    tw.add_argument("--n", type=_pos_int, default=600, help="validation renders")
    tw.add_argument("--towers", default=None,
                    help="comma-separated: cnn and visual priors (default: all of them)")
    tw.add_argument("--sizes", default=None,
                    help="prior input sizes (default: 96,128,160,224 below each prior's own "
                         "input size, and its own)")
    tw.add_argument("--encoder", default=DEFAULT_ENCODER, help="whose render-trained CNN")
    tw.add_argument("--gallery", type=_pos_int, default=840,
                    help="corpus entries searched by the precision@5")
    tw.add_argument("--threads", type=_pos_int, default=2, help="intra-op threads")
    tw.add_argument("--reps", type=_pos_int, default=30, help="timed single-crop calls per point")
    tw.add_argument("--out", default=None,
                    help="chart PNG (default docs/figures/towers.png); the JSON beside it, "
                         "and the HTML figure instead where no PNG exporter works")
    tw.add_argument("--json", action="store_true")
    w = bsub.add_parser("world", help="corpus + test split generation throughput")
    w.add_argument("--corpus-size", default="10k")
    w.add_argument("--workers", type=_pos_int, default=2)
    w.add_argument("--json", action="store_true")


def build_parser() -> argparse.ArgumentParser:
    """The `ratouch` parser: every command sets `module`, the `ratouch.cli` module whose
    `run(args)` runs it."""
    parser = _Parser(prog="ratouch", description=DESCRIPTION)
    parser.add_argument("-v", "--verbose", action="store_true", help="log more")
    sub = parser.add_subparsers(dest="cmd", required=True)
    _add_world(sub)
    _add_corpus(sub)
    _add_train(sub)
    _add_query(sub)
    _add_eval(sub)
    _add_bench(sub)
    _add_judge(sub)
    app = sub.add_parser("app", help="launch the Gradio app")
    app.set_defaults(module="app")
    app.add_argument("--host", default="127.0.0.1")
    app.add_argument("--port", type=_pos_int, default=7860)
    return parser
