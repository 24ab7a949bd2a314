"""`ratouch query`: one RA-Touch query, and its description regenerated with other neighbours.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ratouch.cli.common import usage
from ratouch.images import not_a_file
from ratouch.search.modes import RA_TOUCH_MODE
from ratouch.serve.models import load_model
from ratouch.serve.request import MAX_K, QueryRequest, answer_one, check_k
from ratouch.threads import blas_threads, intra_op_threads


def run(args: argparse.Namespace) -> int:
    check_k(args.k, MAX_K)  # the app's bound, before the models load
    for role, path in (("visual image", args.vision), ("tactile image", args.tactile),
                       ("background image", args.background)):
        if path is None:
            continue
        kind = not_a_file(path)
        if kind is not None:  # /dev/zero, a folder, a pipe: say what it is
            raise usage(f"{role} {path} is {kind}, not an image file")
        if not Path(path).is_file():
            raise usage(f"{role} file {path} does not exist")
    swap = _neighbours_file(args.neighbours_from) if args.neighbours_from else None
    blas_threads(1)  # the serving setting (see ratouch.threads)
    with intra_op_threads(1):
        return _query(args, swap)


def _query(args: argparse.Namespace, swap: list[int] | None) -> int:
    request = QueryRequest.decode(args.vision, args.tactile, box=args.box, k=args.k,
                                  label=args.label, background=args.background,
                                  retrieval=args.retrieval)
    model = load_model(args.encoder, corpus=args.corpus, index=args.index)  # after the checks
    result = answer_one(model, request).to_dict()
    if args.drop is not None or swap is not None:
        reads = (result.get("retrieval") or {}).get("reads", RA_TOUCH_MODE)
        ids = swap if swap is not None else [n["id"] for n in result["neighbours"][reads]]
        drop = set(args.drop or ())
        if drop - set(ids):
            raise usage(f"--drop: {sorted(drop - set(ids))} are not among the neighbours {ids}")
        ids = [i for i in ids if i not in drop]
        result["regenerated"] = model.regenerate(request, ids)
    print(json.dumps(result, indent=1))
    return 0


def _neighbours_file(path: str) -> list[int]:
    """Corpus ids from --neighbours-from: a query's JSON output (its joint neighbours, or a
    regenerated set's) or a JSON list of ids."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise usage(f"--neighbours-from {path}: not a readable JSON file ({e})") from e
    if isinstance(data, dict):
        data = data.get("regenerated", data)
        nb = data.get("neighbours") if isinstance(data, dict) else None
        if isinstance(nb, dict):  # a query's output: {mode: [...]}
            nb = nb.get((data.get("retrieval") or {}).get("reads", RA_TOUCH_MODE))
        data = [n.get("id") if isinstance(n, dict) else n for n in nb] \
            if isinstance(nb, list) else None
    if not isinstance(data, list) or not all(isinstance(i, int) and not isinstance(i, bool)
                                             for i in data):
        raise usage(f"--neighbours-from {path}: expected a query's JSON output or a list of "
                    f"corpus ids")
    return data
