"""`ratouch corpus build`: recaption, sample and embed ImageNet-T, in one process or on Ray.
"""

from __future__ import annotations

import argparse
import json

from ratouch.cli.common import usage
from ratouch.corpus.imagenet_t import build_corpus
from ratouch.corpus.recaption import RecaptionConfig
from ratouch.search.retrieval_side import embed_and_index


def run(args: argparse.Namespace) -> int:
    rc = RecaptionConfig(backend=args.captioner, endpoint=args.endpoint, model=args.model)
    if args.engine == "ray":
        return _run_corpus_ray(args, rc)
    manifest = build_corpus(args.out, args.size, seed=args.seed, recaption=rc,
                            image_list=args.from_list)
    if not args.no_embed:
        manifest = {**manifest, **embed_and_index(args.out, args.encoder, args.index,
                                                  workers=args.workers)}
    print(json.dumps(manifest))
    return 0


def _run_corpus_ray(args: argparse.Namespace, rc) -> int:
    # imported here, not at the top: Ray costs about 1 s that a local build should not pay
    from ratouch.build.ray_corpus import RayOptions, build_corpus_ray

    if args.no_embed:
        raise usage("--no-embed is not supported with --engine ray (it embeds as it goes)")
    opts = RayOptions(address=args.address, num_cpus=args.num_cpus, workers=args.workers,
                      batch_size=args.batch_size, shard_size=args.shard_size,
                      llm_concurrency=args.llm_concurrency, llm_rate=args.llm_rate)
    manifest = build_corpus_ray(args.out, args.size, seed=args.seed, recaption=rc,
                                image_list=args.from_list, encoder=args.encoder,
                                index=args.index, options=opts)
    print(json.dumps(manifest))
    return 0
