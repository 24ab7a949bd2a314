"""What `ratouch train all` runs: every shipped weight retrained in dependency order (the
geometry lookups and firmness models, the encoders, the corpus embeddings, and per encoder
set of the chain the retriever, the trust calibration, the touch gate, the press map, the
language prior, both generators, the gated system's reader and the text system's
generator), then the cascade calibrated over the chain's pipelines (`tests/test_retrain.py`
runs it with every step a stand-in).

It sits above serving and training: the cascade is calibrated by answering validation renders
with the loaded pipelines (`ratouch.ship.cascade`). Each step is a training recipe
(`ratouch.train.recipes`) or a calibration that can also run alone (`ratouch train ...`).
"""

from __future__ import annotations

import shutil

from ratouch.encoders.factory import CHAIN_SETS, ENCODER_ONLY_SETS, create_model, shipped_weights
from ratouch.paths import (
    cascade_calibration,
    generator_weights,
    geometry_calibration,
    trust_calibration,
)
from ratouch.search.retrieval_side import default_corpus
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.ship.cascade import CascadeConfig, calibrate_cascade
from ratouch.timing import Laps
from ratouch.train.encoders import STEPS, TrainConfig, train_encoders
from ratouch.train.gate import gate_recipe
from ratouch.train.geometry import calibrate as calibrate_geometry
from ratouch.train.press_map import PressMapConfig, press_map_recipe
from ratouch.train.recipes import (
    READER_ARM,
    generator_recipe,
    reader_recipe,
    retriever_recipe,
    text_arm_recipe,
)
from ratouch.train.trust import TrustConfig, calibrate


def train_all(seed: int = 0, progress: bool = True, report=print, encoders: bool = True) -> dict:
    """Every shipped weight, in dependency order: the encoders (`CHAIN_SETS` and
    `ENCODER_ONLY_SETS`, the registry's), the corpus embeddings, then for each of `CHAIN_SETS`
    the retriever, the trust calibration, the language prior and both generators, and last
    the cascade over them. Returns the seconds each part took;
    `report` gets each part's own report as it finishes; `encoders=False` starts from the
    encoders already in assets/ (e.g. trained where a GPU was lent)."""
    clock = Laps()
    lap = clock.lap
    # the geometry lookups depend on nothing trained (Taxim's real presses, renders)
    geometry, held_out = calibrate_geometry(seed)
    geometry.save(geometry_calibration())
    report({"geometry": {k: {m: v for m, v in r.items() if m != "presses"}
                         for k, r in held_out.items()}})
    lap("geometry")

    shared: dict = {}
    for name in (*CHAIN_SETS, *ENCODER_ONLY_SETS) if encoders else ():
        tc = TrainConfig(model=name, seed=seed, steps=STEPS.get(name, 300))
        _, rep = train_encoders(tc, out=str(shipped_weights(name)), cache=shared,
                                progress=progress)
        report({"encoders": name, **rep})
        lap(f"encoders_{name}")
    shared.clear()
    for name in (*CHAIN_SETS, *ENCODER_ONLY_SETS):
        default_corpus(name, progress=progress)  # re-embeds: the encoder weights changed
    lap("corpus_embeddings")
    for name in CHAIN_SETS:
        report({"retriever": name, **retriever_recipe(name, seed=seed, progress=progress)})
        lap(f"retriever_{name}")
        # the trust calibration needs only the encoders (the pipelines that read it are
        # loaded for the cascade, last)
        cal = calibrate(create_model(name), TrustConfig(seed=seed), progress=progress)
        cal.save(trust_calibration(name))
        report({"trust": name, **cal.meta})
        lap(f"trust_{name}")
        # the touch gate reads the retriever and the trust calibration's novelty models
        report({"gate": name, **gate_recipe(name, seed=seed)})
        lap(f"gate_{name}")
        # the press map reads the encoders and the corpus's caption embeddings
        report({"press_map": name, **press_map_recipe(name, PressMapConfig(seed=seed))})
        lap(f"press_map_{name}")
        prior = generator_weights(name, "prior")
        if prior.is_dir():
            shutil.rmtree(prior)  # trained on the old encoders' text embeddings
        report({"generators": name, **generator_recipe(name, seed=seed, progress=progress)})
        lap(f"generators_{name}")
        # the gated system's reader: stage 2 again from the new RA-Touch's stage 1
        _, rep = reader_recipe(name, generator_weights(name, "ra"), seed=seed,
                               out=generator_weights(name, "reader"), progress=progress,
                               arm=READER_ARM)
        report({"reader": name, **{k: v for k, v in rep.items() if k != "history"}})
        lap(f"reader_{name}")
        # the text system's generator: stage 2 again, the neighbours' captions in the prompt
        _, rep = text_arm_recipe(name, generator_weights(name, "ra"), seed=seed,
                                 out=generator_weights(name, "text"), progress=progress)
        report({"text": name, **{k: v for k, v in rep.items() if k != "history"}})
        lap(f"text_{name}")
    cascade = calibrate_cascade([RATouchPipeline.load(n, progress=progress)
                                 for n in CHAIN_SETS], CascadeConfig(seed=seed))
    cascade.save(cascade_calibration("+".join(CHAIN_SETS)))
    report({"cascade": list(CHAIN_SETS), "measure": cascade.measure,
            "thresholds": list(cascade.thresholds)})
    lap("cascade")
    times = clock.seconds(1)
    return {"seconds": times, "total_s": round(sum(times.values()), 1)}
