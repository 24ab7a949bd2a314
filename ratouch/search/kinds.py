"""The index kinds (`ratouch.search.index.VectorIndex`) by role, in a module that imports
nothing, so that the command line offers them as choices without loading faiss.
`ratouch.search.index` re-exports them."""

from __future__ import annotations

#: Every kind of index: "flat" (exact inner product), "hnsw" (a graph), "ivfpq" (inverted
#: lists over product-quantised codes), "ivfflat" (inverted lists of full vectors).
KINDS = ("flat", "hnsw", "ivfpq", "ivfflat")

#: The inverted-list kinds: trained on a sample, searched with `nprobe`; their lists can
#: live on disk (`VectorIndex.build_ondisk`).
ONDISK_KINDS = ("ivfflat", "ivfpq")

#: The approximate kinds, measured against exact search (`ratouch bench retrieval --corpus`).
APPROXIMATE_KINDS = ("hnsw", "ivfflat", "ivfpq")

#: The in-memory kinds the speed benchmarks compare by default (`ratouch bench retrieval`,
#: `ratouch bench tradeoff`); ivfflat is built for the on-disk corpus.
BENCH_KINDS = ("flat", "hnsw", "ivfpq")
