"""Shared fixtures: a default world and a test split written once per session, a tiny LLaMA
folder, a pipeline over a small corpus embedded with the shipped encoder, and a local
OpenAI-compatible server for the LLM recaptioner and judge."""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from types import SimpleNamespace

import numpy as np
import pytest

from ratouch.errors import DataError, RATouchError
from ratouch.paths import generator_weights
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import write_split
from ratouch.world.sampler import World


def pytest_configure(config):
    """Under pytest-xdist (`make test` runs the suite on two workers), each worker's share of
    the cores for its intra-op threads, and for the processes its tests start: with two
    threads each on two cores, OpenMP's waiting threads spin against the other worker's
    (SmolLM2's greedy-decoding tests took 37-42 s each, under 3.5 s in one process). Nothing changes without
    xdist."""
    import os

    workers = os.environ.get("PYTEST_XDIST_WORKER_COUNT")
    if not workers:
        return
    share = str(max(1, (os.cpu_count() or 1) // int(workers)))
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, share)  # read by the processes the tests start
    import torch
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(int(share))
    threadpool_limits(int(share))  # numpy's BLAS in this worker


@pytest.fixture(scope="module")
def one_thread():
    """Tiny models on one intra-op thread (more only add overhead on shared cores); a test
    module asks for it with `pytestmark = pytest.mark.usefixtures("one_thread")`."""
    from ratouch.threads import intra_op_threads

    with intra_op_threads(1):
        yield


@pytest.fixture(scope="session")
def world() -> World:
    return World(WorldConfig(seed=0))


@pytest.fixture(scope="session")
def test_split_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("tvl_world")
    counts = write_split(WorldConfig(seed=0), root, "test", workers=2, progress=False)
    return root, counts


@pytest.fixture(scope="session")
def debug_encoders():
    """The tiny `debug` encoder set with fixed random weights (MiniLM is real)."""
    import torch

    from ratouch.encoders.factory import create_model

    torch.manual_seed(0)
    return create_model("debug", pretrained=None).eval()


@pytest.fixture(scope="session")
def debug_checkpoints(tmp_path_factory):
    """Two checkpoint folders of the `debug` encoders with different random weights: the
    encoder before and after a retraining."""
    import torch

    from ratouch.checkpoint import save_checkpoint
    from ratouch.encoders.factory import create_model, model_config

    root = tmp_path_factory.mktemp("debug-weights")
    folders = []
    for seed in (1, 2):
        torch.manual_seed(seed)
        model = create_model("debug", pretrained=None)
        folders.append(save_checkpoint(root / f"seed{seed}", model.state_dict(),
                                       model_config("debug")))
    return folders


@pytest.fixture(scope="session")
def small_corpus(tmp_path_factory, debug_encoders):
    """A 240-entry world corpus embedded with the debug encoders."""
    from ratouch.corpus.embed import embed_corpus
    from ratouch.corpus.imagenet_t import build_corpus

    folder = tmp_path_factory.mktemp("corpus") / "c"
    build_corpus(folder, 240, seed=0, progress=False)
    embed_corpus(folder, debug_encoders, batch=100, workers=1, progress=False)
    return folder


@pytest.fixture(scope="session")
def debug_pipeline(debug_encoders, small_corpus):
    """A whole `RATouchPipeline` without trained weights: the debug encoders over the
    240-entry corpus, a random Tactile-Guided Retriever and two tiny random generators, no
    trust calibration. Its answers mean nothing; its query path is the real one."""
    import torch

    from ratouch.model.decoder import DecoderConfig, build_small_decoder
    from ratouch.model.generator import BaselinePrompt, PromptConfig, RATouchGenerator
    from ratouch.model.integrator import IntegratorConfig, TextureAwareIntegrator
    from ratouch.model.retriever import RetrieverConfig, TactileGuidedRetriever
    from ratouch.search.index import IndexConfig
    from ratouch.search.retrieval import CorpusIndex, CorpusSearch
    from ratouch.serve.pipeline import RATouchPipeline
    from ratouch.vocabulary import TVL_ADJECTIVES

    dim = debug_encoders.dim

    def generator(integrator: bool):
        cfg = DecoderConfig(hidden=32, layers=2, heads=2, intermediate=64, max_new_tokens=6,
                            lora_r=4, lora_alpha=8)
        return RATouchGenerator(
            BaselinePrompt(PromptConfig(dim=dim, out_dim=32)),
            build_small_decoder(cfg, TVL_ADJECTIVES[:48], seed=0),
            TextureAwareIntegrator(IntegratorConfig(dim=dim, out_dim=32)) if integrator
            else None).eval()

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        tgr = TactileGuidedRetriever(RetrieverConfig(dim=dim, cross_residual=True)).eval()
        ra, base = generator(True), generator(False)
    index = CorpusIndex(small_corpus, debug_encoders.name, dim, IndexConfig(kind="flat"))
    return RATouchPipeline(CorpusSearch(debug_encoders, index), tgr, ra, base)


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    """Tests never read or write the user's cache of corpora and training data."""
    import os

    old = os.environ.get("RATOUCH_CACHE")
    os.environ["RATOUCH_CACHE"] = str(tmp_path_factory.mktemp("ratouch-cache"))
    yield
    if old is None:
        os.environ.pop("RATOUCH_CACHE", None)
    else:
        os.environ["RATOUCH_CACHE"] = old


def write_tiny_llama(folder) -> None:
    """A random 2-layer LlamaForCausalLM (hidden 64, ~300 words) and its fast tokenizer, in the
    HF folder layout a real LLaMA-2 checkpoint has (for the decoder's real-path wiring)."""
    import torch
    from tokenizers import Tokenizer, models, pre_tokenizers
    from transformers import LlamaConfig, LlamaForCausalLM, PreTrainedTokenizerFast

    from ratouch.model.decoder import PROMPT
    from ratouch.vocabulary import TVL_ADJECTIVES

    words = (["<unk>", "<s>", "</s>", "<pad>", ",", "?", "."] + PROMPT[:-1].split()
             + list(TVL_ADJECTIVES) + [f"w{i}" for i in range(230)])
    vocab = {w: i for i, w in enumerate(dict.fromkeys(words))}
    tok = Tokenizer(models.WordLevel(vocab=vocab, unk_token="<unk>"))
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    PreTrainedTokenizerFast(tokenizer_object=tok, bos_token="<s>", eos_token="</s>",
                            unk_token="<unk>", pad_token="<pad>").save_pretrained(folder)
    cfg = LlamaConfig(vocab_size=len(vocab), hidden_size=64, intermediate_size=128,
                      num_hidden_layers=2, num_attention_heads=4, num_key_value_heads=4,
                      bos_token_id=1, eos_token_id=2, pad_token_id=3)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        LlamaForCausalLM(cfg).save_pretrained(folder)


@pytest.fixture(scope="session")
def tiny_llama(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tiny-llama")
    write_tiny_llama(folder)
    return folder


@pytest.fixture(scope="session")
def shipped_corpus(tmp_path_factory):
    """A 600-entry world corpus (seed 0) embedded with the shipped default encoder, built once
    per session: the fake-free pipelines (`pipeline`, `real_pipeline`) and the CLI tests read
    it, none writes to it."""
    from ratouch.corpus.imagenet_t import MANIFEST, build_corpus
    from ratouch.search.retrieval_side import embed_and_index

    folder = tmp_path_factory.getbasetemp() / "corpus-600"
    if not (folder / MANIFEST).is_file():
        build_corpus(folder, 600, seed=0, progress=False)
    embed_and_index(folder, "default-s", workers=1, progress=False)  # a no-op once done
    return folder


@pytest.fixture(scope="session")
def pipeline(shipped_corpus):
    from ratouch.serve.pipeline import RATouchPipeline

    return RATouchPipeline.load("default-s", corpus=shipped_corpus)


class FakeLLM:
    """State shared with the fake server's handler: what to answer and what was received."""

    def __init__(self, reply: str) -> None:
        self.reply = reply
        self.mode = "ok"  # ok | http500 | badjson | sleep | echo | grade
        self.sleep_s = 1.0
        self.requests: list[dict] = []
        self.lock = threading.Lock()
        self.endpoint = ""


def _grade(prompt: str) -> str:
    """A judge reply to the TVL judge prompt: the share of the answer's words in the label."""
    fields = {}
    for line in prompt.splitlines():
        for key in ("[Assistant's answer]: ", "[Correct answer]: "):
            if line.startswith(key):
                fields[key] = {w.strip(" .").lower() for w in line[len(key):].split(",")}
    answer, label = fields["[Assistant's answer]: "], fields["[Correct answer]: "]
    return f"{1 + 9 * len(answer & label) / max(len(answer), 1):.1f}\nshare of matched words"


def _fake_llm_handler(state: FakeLLM):
    class Handler(BaseHTTPRequestHandler):
        def do_POST(self):  # noqa: N802 (http.server API)
            body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
            with state.lock:
                state.requests.append({"path": self.path, "headers": dict(self.headers),
                                       "body": body})
            if state.mode == "sleep":
                time.sleep(state.sleep_s)
            if state.mode == "http500":
                self.send_error(500, "boom")
                return
            if state.mode == "badjson":
                data = b"{not json"
            else:
                content = state.reply
                if state.mode == "grade":  # a judge: 1 + 9 * share of answer words in the label
                    content = _grade(body["messages"][-1]["content"])
                if state.mode == "echo":  # answer depends on the class name in the prompt
                    prompt = body["messages"][0]["content"]
                    line = next(x for x in prompt.splitlines() if x.startswith("Class: "))
                    content = {"pan": "hard, metallic, smooth, rigid, solid",
                               "bear": "soft, furry, plush, fluffy, cushioned",
                               "rock": "rough, hard, craggy, uneven, gritty"}[line[len("Class: "):]]
                message = {"role": "assistant", "content": content}
                data = json.dumps({"choices": [{"index": 0, "message": message}]}).encode()
            try:
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)
            except OSError:
                pass  # the client gave up (timeout test)

        def log_message(self, format, *args):  # noqa: A002 - keep test output quiet
            pass

    return Handler


@contextlib.contextmanager
def serve_fake_llm(monkeypatch, reply: str):
    """A real OpenAI-compatible chat-completions server on 127.0.0.1 (random port), proxies
    cleared; yields its `FakeLLM` state (``.endpoint`` is the base URL)."""
    for var in ("http_proxy", "HTTP_PROXY", "https_proxy", "HTTPS_PROXY", "all_proxy", "ALL_PROXY"):
        monkeypatch.delenv(var, raising=False)
    state = FakeLLM(reply)
    server = ThreadingHTTPServer(("127.0.0.1", 0), _fake_llm_handler(state))
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.02},
                              daemon=True)
    thread.start()
    state.endpoint = f"http://127.0.0.1:{server.server_address[1]}/v1"
    try:
        yield state
    finally:
        server.shutdown()
        server.server_close()


#: The shipped default-s retriever and generators are in assets/ (a clone has them).
HAVE_ASSETS = (generator_weights("default-s", "ra") / "manifest.json").is_file()


@pytest.fixture(scope="session")
def real_pipeline(shipped_corpus):
    """The real pipeline (shipped default-s weights) on the session's 600-entry world corpus
    (`shipped_corpus`), loaded once per session and shared, read-only, by every test that needs
    it."""
    from ratouch.serve.pipeline import RATouchPipeline

    if not HAVE_ASSETS:
        pytest.skip("the trained retriever/generator weights are not in assets/")
    return RATouchPipeline.load("default-s", corpus=shipped_corpus)


# ------------------------------------------------------------------------- a fake pipeline
# for the app's tests: the query's output shape, with the library's real input checks

class FakeCorpus:
    def __init__(self, n: int):
        self.entries = [SimpleNamespace(class_name=f"class{i % 7}", caption=f"soft, grainy {i}",
                                        source=f"world:0:{i % 7}:{i}", material="")
                        for i in range(n)]

    def thumbnail(self, i: int, size: int = 96) -> np.ndarray:
        rng = np.random.default_rng(i)
        return np.full((size, size, 3), rng.integers(0, 255, 3), np.uint8)


class FakePipeline:
    """An `Answerer` (`ratouch.serve.request`) with `RATouchPipeline.answer`'s result shape;
    its requests are decoded by the library (`QueryRequest.decode`, the real input checks),
    as the app sends them.

    The image query returns ids 0..k-1, the tactile query 2..k+1, the joint one 1..k: ids 2..k-1
    are shared by all three modes, 1 by image and joint, k by tactile and joint.
    """

    name = "fake"

    def __init__(self, n: int = 60, delay_s: float = 0.0):
        self.corpus = FakeCorpus(n)
        self.encoders = SimpleNamespace(name=self.name, dim=8)
        self.delay_s = delay_s
        self.calls: list[dict] = []

    def model(self, name=None) -> "FakePipeline":
        return self

    def answer(self, requests) -> list:
        out = []
        for req in requests:
            try:
                out.append(self._answer(req))
            except RATouchError as e:
                out.append(e)
        return out

    def _answer(self, req):
        from ratouch.serve.request import QueryResult, check_k

        check_k(req.k, len(self.corpus.entries))
        frame = req.frame
        self.calls.append({"crop": req.crop.shape, "box": list(req.box), "k": req.k,
                           "label": req.label, "tactile": frame is not None,
                           "background": req.background is not None, "model": req.model,
                           "retrieval": req.retrieval})
        time.sleep(self.delay_s)
        k = req.k
        # the built-in modes at fixed offsets; a mode registered by a test follows them
        from ratouch.search.modes import QUERY_MODES

        offsets = {"image": 0, "tactile": 2, "joint": 1}
        starts = {m: offsets.get(m, 3 + i) for i, m in enumerate(QUERY_MODES)
                  if frame is not None or not QUERY_MODES[m].needs_touch}
        neighbours = {m: [self._neighbour(i, 0.9 - 0.01 * r)
                          for r, i in enumerate(range(s, s + k))] for m, s in starts.items()}
        points = [{"role": f"query_{m}", "x": float(j), "y": 1.0} for j, m in enumerate(starts)]
        points += [{"role": f"neighbour_{m}", "x": 0.1 * n["id"], "y": -0.1 * n["id"],
                    "id": n["id"]} for m, ns in neighbours.items() for n in ns]
        if req.label:
            points.append({"role": "ground_truth", "x": 0.5, "y": 0.5})
        return QueryResult(
            neighbours=neighbours,
            description={"ra_touch": "soft and grainy" if frame is not None else "",
                         "baseline": "smooth" if frame is not None else ""},
            attention={}, pca={"points": points, "explained": [0.3, 0.2]},
            timings_ms={"preprocess": 1.0, "encode_image": 2.0, "total": 3.0},
            warnings=list(req.warnings), box=[int(v) for v in req.box], encoder=self.name,
            visual_route={"route": "render"}, trust=None)

    def regenerate(self, request, neighbours) -> dict:
        if request.frame is None:
            raise DataError("regenerating the RA-Touch description needs a tactile image")
        self.calls.append({"regenerate": list(neighbours), "box": list(request.box),
                           "retrieval": request.retrieval})
        return {"description": {"ra_touch": f"read {len(neighbours)} neighbours"},
                "neighbours": [self._neighbour(i, 0.5) for i in neighbours],
                "attention": {"image": [0.1] * len(neighbours), "text": [0.1] * len(neighbours)},
                "timings_ms": {"total": 2.0}}

    def _neighbour(self, i: int, score: float) -> dict:
        e = self.corpus.entries[i]
        return {"id": i, "score": round(score, 4), "class_name": e.class_name,
                "caption": e.caption, "description": "", "source": e.source}


def free_port() -> int:
    """A free TCP port on 127.0.0.1 (servers in tests listen there only)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
