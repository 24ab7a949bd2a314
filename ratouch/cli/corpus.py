"""`ratouch corpus build`: recaption, sample and embed ImageNet-T, in one process or on Ray;
`ratouch corpus recaption`: a folder of one's own images (FOLDER/<class>/<image>) recaptioned
offline into a corpus folder, which `corpus build --from-list FOLDER` then embeds.

Run again with the same `--out`, the command finishes what a killed run left: a corpus that is
the one asked for is kept, its embeddings resume where they stopped and missing indexes are
built (it says so on stderr); `--overwrite` replaces whatever corpus the folder holds, and
`--reindex` builds the encoder's indexes again (after one was refused as corrupt).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from ratouch.cli.common import usage
from ratouch.corpus.embed import EMBED_MANIFEST, embedding_progress, embeddings_dir
from ratouch.corpus.imagenet_t import MANIFEST, build_corpus, read_image_folder
from ratouch.corpus.recaption import RecaptionConfig
from ratouch.search.retrieval import index_folder
from ratouch.search.retrieval_side import embed_and_index


def run(args: argparse.Namespace) -> int:
    if args.corpus_cmd == "recaption":
        return _recaption(args)
    rc = RecaptionConfig(backend=args.captioner, endpoint=args.endpoint, model=args.model)
    out = Path(args.out)
    if args.overwrite and (out / MANIFEST).is_file():
        shutil.rmtree(out)
        print(f"removed the corpus in {out} (--overwrite)", file=sys.stderr)
    if args.engine == "ray":
        return _run_corpus_ray(args, rc)
    resumed = (out / MANIFEST).is_file()
    manifest = build_corpus(out, args.size, seed=args.seed, recaption=rc,
                            image_list=args.from_list, resume=True)
    if resumed:
        print(f"{out} already holds this corpus ({manifest['size']} entries): kept",
              file=sys.stderr)
    if not args.no_embed:
        _say_embedding_state(out, args)
        manifest = {**manifest, **embed_and_index(out, args.encoder, args.index,
                                                  workers=args.workers)}
    print(json.dumps({**manifest, "resumed": resumed}))
    return 0


def _recaption(args: argparse.Namespace) -> int:
    """Check the folder (every image opened), then recaption and write the corpus (nothing is
    written when the folder is refused)."""
    out = Path(args.out)
    if (out / MANIFEST).is_file():
        raise usage(f"{out} already holds a corpus; choose another --out")
    rows = read_image_folder(args.images)
    rc = RecaptionConfig(backend=args.recaptioner)
    manifest = build_corpus(out, len(rows), recaption=rc, image_list=args.images,
                            progress=sys.stderr.isatty())
    print(json.dumps(manifest))
    print(f"wrote {manifest['size']} entries of {manifest['n_classes']} classes to {out}; "
          f"embed them with `ratouch corpus build --out {out} --from-list {args.images} "
          f"--captioner {args.recaptioner}`", file=sys.stderr)
    return 0


def _say_embedding_state(out: Path, args: argparse.Namespace) -> None:
    """Say what of an earlier run is resumed or redone: embeddings, indexes."""
    done = embedding_progress(out, args.encoder)
    if done is not None:
        print(f"resuming the {args.encoder} embeddings of {out} at {done[0]} / {done[1]}",
              file=sys.stderr)
    if args.reindex:
        _remove_indexes(out, args)
    elif (embeddings_dir(out, args.encoder) / EMBED_MANIFEST).is_file():
        print(f"the {args.encoder} embeddings of {out} are finished: checked, not redone",
              file=sys.stderr)


def _remove_indexes(out: Path, args: argparse.Namespace) -> None:
    """--reindex: the encoder's indexes of the kind asked are removed, so the build makes
    them again (the local engine and Ray alike)."""
    for key in ("image", "text"):
        folder = index_folder(out, args.encoder, key, args.index)
        if folder.exists():
            shutil.rmtree(folder)
            print(f"removed the index {folder} (--reindex): built again", file=sys.stderr)


def _run_corpus_ray(args: argparse.Namespace, rc) -> int:
    # imported here, not at the top: Ray costs about 1 s that a local build should not pay
    from ratouch.distributed.ray_corpus import RayOptions, build_corpus_ray

    if args.no_embed:
        raise usage("--no-embed is not supported with --engine ray (it embeds as it goes)")
    if args.reindex:
        _remove_indexes(Path(args.out), args)
    opts = RayOptions(address=args.address, num_cpus=args.num_cpus, workers=args.workers,
                      batch_size=args.batch_size, shard_size=args.shard_size,
                      llm_concurrency=args.llm_concurrency, llm_rate=args.llm_rate)
    manifest = build_corpus_ray(args.out, args.size, seed=args.seed, recaption=rc,
                                image_list=args.from_list, encoder=args.encoder,
                                index=args.index, options=opts)
    print(json.dumps(manifest))
    return 0
