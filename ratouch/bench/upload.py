"""`ratouch bench upload`: what a huge tactile upload costs, stage by stage, and how much it
delays a normal query running beside it on the same server (two client threads on one
`QueryBatcher`, as the app serves them)."""

from __future__ import annotations

import os
import statistics
import tempfile
import threading
import time

import numpy as np
from PIL import Image

from ratouch.images import QUERY_MAX_SIDE, resize_array, to_rgb_array
from ratouch.serve.batcher import QueryBatcher
from ratouch.serve.pipeline import RATouchPipeline
from ratouch.serve.request import QueryRequest, answer_one
from ratouch.world.sampler import World


def write_big_frame(path: str, side: int, seed: int = 0) -> str:
    """A world tactile frame scaled up to `side` x `side` with pixel noise (so PNG cannot
    compress it away), written as PNG."""
    s = World().sample("test", 60)
    big = resize_array(s.tactile, side)
    noise = np.random.default_rng(seed).integers(0, 4, big.shape, dtype=np.uint8)
    Image.fromarray(big + noise).save(path, compress_level=1)
    return path


def _ms(t0: float) -> float:
    return round((time.perf_counter() - t0) * 1000, 1)


def stage_times(path: str) -> dict:
    """Decode (PIL load), reduce (to QUERY_MAX_SIDE), and the whole bounded decode."""
    t0 = time.perf_counter()
    with Image.open(path) as img:
        img.load()
        t1 = time.perf_counter()
        img.resize((QUERY_MAX_SIDE, QUERY_MAX_SIDE), Image.Resampling.BILINEAR, reducing_gap=2.0)
        t2 = time.perf_counter()
    t3 = time.perf_counter()
    to_rgb_array(path, name="tactile image", max_side=QUERY_MAX_SIDE)
    return {"decode_ms": round((t1 - t0) * 1000, 1), "reduce_ms": round((t2 - t1) * 1000, 1),
            "bounded_to_rgb_array_ms": _ms(t3)}


def _ask(server: QueryBatcher, req: dict):
    """One query through the server, decoded in the calling thread as the app does."""
    return answer_one(server, QueryRequest.decode(**req))


def _timed(server, req: dict, out: dict, key: str) -> None:
    t0 = time.perf_counter()
    out[key] = _ask(server, req)
    out[key + "_ms"] = _ms(t0)


def _pair(server, first: dict, second: dict, gap_s: float) -> dict:
    """Start `first`, then `second` `gap_s` later, in two client threads; both latencies."""
    out: dict = {}
    a = threading.Thread(target=_timed, args=(server, first, out, "first"))
    a.start()
    time.sleep(gap_s)
    _timed(server, second, out, "second")
    a.join()
    return out


def bench_upload(encoder: str = "default-s", corpus=None, side: int = 6000, repeats: int = 3,
                 gap_s: float = 0.05) -> dict:
    """Measure the huge upload alone, a normal query alone, and the normal query started
    `gap_s` after a huge upload (and, for comparison, after another normal query).

    Returns:
        Median latencies in ms, the stage split of the huge upload's decoding, its
        `timings_ms`, and the delay of the normal query beside it.
    """
    pipe = RATouchPipeline.load(encoder, corpus=corpus)
    server = QueryBatcher(pipe)
    s = World().sample("test", 60)
    with tempfile.TemporaryDirectory(prefix="ratouch-upload-") as tmp:
        big = write_big_frame(os.path.join(tmp, "tactile.png"), side)
        visual = os.path.join(tmp, "visual.png")
        Image.fromarray(s.visual).save(visual)
        normal = {"visual": visual, "tactile": s.tactile, "box": s.box}
        huge = {"visual": visual, "tactile": big, "box": s.box}
        _ask(server, normal)  # warm-up
        stages = stage_times(big)
        file_mb = round(os.path.getsize(big) / 1e6, 1)
        runs: dict[str, list] = {k: [] for k in ("huge", "normal", "beside_huge", "beside_normal")}
        last = None
        for _ in range(repeats):
            t0 = time.perf_counter()
            last = _ask(server, huge)
            runs["huge"].append(_ms(t0))
            t0 = time.perf_counter()
            _ask(server, normal)
            runs["normal"].append(_ms(t0))
            runs["beside_huge"].append(_pair(server, huge, normal, gap_s)["second_ms"])
            runs["beside_normal"].append(_pair(server, normal, normal, gap_s)["second_ms"])
    med = {k: statistics.median(v) for k, v in runs.items()}
    assert last is not None  # the medians above need at least one repeat
    return {"side": side, "file_mb": file_mb, "repeats": repeats, "max_side": QUERY_MAX_SIDE,
            "cpu_count": os.cpu_count(), "load_average_1m": round(os.getloadavg()[0], 2),
            "median_ms": med, "runs_ms": runs, "huge_decode": stages,
            "huge_timings_ms": last.timings_ms,
            "delay_beside_huge_ms": round(med["beside_huge"] - med["normal"], 1),
            "delay_beside_normal_ms": round(med["beside_normal"] - med["normal"], 1),
            "targets": {"huge_ms": 2000, "delay_ms": 500}}
