"""`ratouch bench corpus`: throughput of the corpus build (plan, recaption, render, embed,
write, index) on the local single-process engine or on Ray, and peak memory.

Stage figures: for the local engine the wall seconds of each sequential phase; for Ray the
busy seconds of each stage summed over its workers (so entries_per_s is per worker), plus the
end-to-end wall clock for both. Peak memory is the largest summed RSS of this process and all
its descendants (Ray's raylet, workers and actors included), sampled every 0.2 s.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

import psutil

from ratouch.corpus.embed import embed_corpus
from ratouch.corpus.imagenet_t import build_corpus
from ratouch.encoders.factory import create_model
from ratouch.errors import ConfigError
from ratouch.search.index import IndexConfig
from ratouch.search.retrieval import CorpusIndex
from ratouch.timing import Laps

ENGINES = ("local", "ray")


class PeakRSS:
    """Samples the summed RSS of this process tree in a thread; `.peak_mb` once stopped."""

    def __init__(self, interval_s: float = 0.2) -> None:
        self.interval_s, self.peak = interval_s, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _sample(self) -> int:
        me = psutil.Process()
        total = me.memory_info().rss
        for child in me.children(recursive=True):
            try:
                total += child.memory_info().rss
            except psutil.Error:
                pass
        return total

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, self._sample())
            self._stop.wait(self.interval_s)

    def __enter__(self) -> "PeakRSS":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    @property
    def peak_mb(self) -> float:
        return round(self.peak / 2**20, 1)


def _local(out: Path, n: int, workers: int, encoder: str) -> dict:
    """The single-process build, phase by phase, as `ratouch corpus build` runs it."""
    clock = Laps()
    build_corpus(out, n, seed=0, progress=False)
    clock.lap("plan_recaption")
    model = create_model(encoder)
    embed_corpus(out, model, workers=workers, progress=False)
    clock.lap("render_embed")
    CorpusIndex(out, model.name, model.dim, IndexConfig(kind="flat"))
    clock.lap("index")
    return {s: {"seconds": round(v, 3), "entries_per_s": round(n / v, 1)}
            for s, v in clock.laps.items()}


def _ray(out: Path, n: int, workers: int, encoder: str, batch_size: int) -> dict:
    from ratouch.distributed.ray_corpus import RayOptions, build_corpus_ray  # imports Ray (heavy)

    r = build_corpus_ray(out, n, seed=0, encoder=encoder,
                         options=RayOptions(workers=workers, batch_size=batch_size))
    return {s: {"busy_s": v["busy_s"], "entries_per_s": v["entries_per_s"]}
            for s, v in r["stages"].items()}


def bench_corpus(engine: str = "ray", n: int = 2000, workers: int = 2,
                 encoder: str = "default-s", batch_size: int = 250) -> dict:
    """Build a world corpus of `n` entries into a temporary folder and time it.

    Returns:
        {engine, n, workers, cpu_count, stages: {name: {entries_per_s, ...}},
        end_to_end: {seconds, entries_per_s}, peak_rss_mb}.
    """
    if engine not in ENGINES:
        raise ConfigError(f"engine={engine!r} must be one of {ENGINES}")
    tmp = Path(tempfile.mkdtemp(prefix="ratouch-bench-corpus-"))
    try:
        with PeakRSS() as mem:
            t0 = time.perf_counter()
            if engine == "local":
                stages = _local(tmp / "c", n, workers, encoder)
            else:
                stages = _ray(tmp / "c", n, workers, encoder, batch_size)
            wall = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"engine": engine, "n": n, "workers": workers, "cpu_count": os.cpu_count(),
            "encoder": encoder, "stage_time": "wall" if engine == "local" else
            "busy, summed over workers", "stages": stages,
            "end_to_end": {"seconds": round(wall, 2), "entries_per_s": round(n / wall, 1)},
            "peak_rss_mb": mem.peak_mb}


def format_corpus_bench(r: dict) -> str:
    """A short human-readable report of `bench_corpus`."""
    lines = [f"corpus build, engine {r['engine']}, {r['n']} entries, {r['workers']} workers, "
             f"{r['cpu_count']} cores (stage time: {r['stage_time']}):"]
    for s, v in r["stages"].items():
        lines.append(f"  {s:<15} {v['entries_per_s']:>10.1f} entries/s")
    e = r["end_to_end"]
    lines.append(f"  end to end      {e['entries_per_s']:>10.1f} entries/s ({e['seconds']:.1f} s)")
    lines.append(f"  peak memory     {r['peak_rss_mb']:.0f} MB (process tree RSS)")
    return "\n".join(lines)
