"""Retrieval quality on the world's test split, per setting: material precision@K (retrieved
entries made of the query's material) and label-adjective overlap@K (share of the query's
ground-truth adjectives found in a retrieved tactile caption), with chance levels, overall and
on the look-alike / feel-alike groups."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ratouch.search.retrieval import CorpusSearch
from ratouch.vocabulary import parse_adjectives
from ratouch.world.config import WorldConfig
from ratouch.world.material import material
from ratouch.world.sampler import TEST_SIZE, World


def split_queries(world_cfg: WorldConfig, n: int = TEST_SIZE) -> dict:
    """Visual crops (contact box), tactile frames, backgrounds and ground truth of the test
    split."""
    world = World(world_cfg)
    crops, tacs, bgs, mats, labels = [], [], [], [], []
    for i in range(n):
        s = world.sample("test", i)
        crops.append(s.crop)
        tacs.append(s.tactile)
        bgs.append(world.background_image(s.sensor))
        mats.append(s.material)
        labels.append(set(s.label))
    return {"crops": crops, "tactiles": tacs, "backgrounds": bgs, "materials": mats,
            "labels": labels}


def entry_materials(corpus) -> np.ndarray:
    """The world material of every corpus entry, by id."""
    return np.array([e.material for e in corpus.entries])


def material_precision(ids: np.ndarray, materials: Sequence[str], entry_mats: np.ndarray
                       ) -> np.ndarray:
    """Material precision@K per query: the share of its retrieved entries (ids: (N, K)) made
    of the query's material (`entry_mats` from `entry_materials`). Its mean is P@K."""
    return (entry_mats[np.asarray(ids)] == np.asarray(materials)[:, None]).mean(1)


def retrieval_metrics(ids: np.ndarray, mats: Sequence[str], labels: Sequence[set], entry_mats: np.ndarray,
             entry_words: list[set], k: int, sel: np.ndarray) -> dict:
    top = ids[sel, :k]
    prec = float(material_precision(top, np.asarray(mats)[sel], entry_mats).mean())
    lab = [labels[int(i)] for i in np.nonzero(sel)[0]]
    overlap = float(np.mean([np.mean([len(words & entry_words[j]) / len(words) for j in row])
                             for words, row in zip(lab, top)]))
    return {"material_precision": round(prec, 4), "adjective_overlap": round(overlap, 4)}


def evaluate_retrieval(retriever: CorpusSearch, world_cfg: WorldConfig | None = None,
                       ks: Sequence[int] = (1, 5, 7), queries: dict | None = None,
                       joint_fn=None) -> dict:
    """Quality of every available setting at each K.

    Args:
        retriever: encoders + corpus index (a world corpus, whose entries know their material).
        world_cfg: the world whose test split is queried.
        ks: values of K.
        queries: precomputed `split_queries(...)` (optional).
        joint_fn: (V, T) -> joint queries (the Tactile-Guided Retriever), if available.

    Returns:
        {"settings": {name: {"all"|"look_alike"|"feel_alike": {K: metrics}}}, "chance": ...}
    """
    world_cfg = world_cfg or WorldConfig()
    q = queries or split_queries(world_cfg)
    emb = retriever.embed_queries(q["crops"], q["tactiles"], q["backgrounds"], joint_fn)
    kmax = max(ks)
    results = retriever.retrieve(emb, kmax)
    entries = retriever.corpus.entries
    entry_mats = entry_materials(retriever.corpus)
    entry_words = [set(parse_adjectives(e.caption)) for e in entries]
    mats = q["materials"]
    subsets = {
        "all": np.ones(len(mats), bool),
        "look_alike": np.array([material(m).look_group is not None for m in mats]),
        "feel_alike": np.array([material(m).feel_group is not None for m in mats]),
    }
    out: dict = {"n_queries": len(mats), "corpus_size": len(entries), "settings": {}}
    for name, (_, ids) in results.items():
        out["settings"][name] = {
            sub: {str(k): retrieval_metrics(ids, mats, q["labels"], entry_mats, entry_words, k, sel)
                  for k in ks}
            for sub, sel in subsets.items() if sel.any()}
    # chance: K random corpus entries
    rng = np.random.default_rng(0)
    rand = rng.integers(len(entries), size=(len(mats), kmax))
    out["chance"] = {str(k): retrieval_metrics(rand, mats, q["labels"], entry_mats, entry_words, k,
                                      subsets["all"]) for k in ks}
    return out


def format_retrieval_eval(r: dict) -> str:
    ks = list(r["chance"])
    lines = [f"retrieval quality: {r['n_queries']} test queries, corpus of {r['corpus_size']}",
             f"{'setting':<15}{'subset':<12}" + "".join(f"  P@{k:<3} ovl@{k:<3}" for k in ks)]
    for name, subs in r["settings"].items():
        for sub, per_k in subs.items():
            cells = "".join(f"  {per_k[k]['material_precision']:.3f} {per_k[k]['adjective_overlap']:.3f} "
                            for k in ks)
            lines.append(f"{name:<15}{sub:<12}{cells}")
    cells = "".join(f"  {r['chance'][k]['material_precision']:.3f} {r['chance'][k]['adjective_overlap']:.3f} "
                    for k in ks)
    lines.append(f"{'chance':<15}{'all':<12}{cells}")
    return "\n".join(lines)
