"""The corpus build on Ray Data: same result as the single-process build, no deadlock on two
cores, resumable checksummed shards, a real local Ray cluster (head + one worker), the LLM
stage against the fake OpenAI-compatible server, and a worker killed mid-build."""

from __future__ import annotations

import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
from PIL import Image

from conftest import serve_fake_llm
from ratouch.checkpoint import sha256_file
from ratouch.corpus.embed import load_embeddings
from ratouch.corpus.imagenet_t import build_corpus, load_corpus, world_lexicon
from ratouch.corpus.recaption import OfflineRecaptioner
from ratouch.distributed.ray_corpus import SHARD_DIR, plan_cpus
from ratouch.errors import ConfigError
from ratouch.processes import _running, tagged
from ratouch.search.retrieval_side import embed_and_index, open_retriever

REPO = Path(__file__).resolve().parents[1]
N = 360  # entries of the fast comparison (the 2k one is marked slow)
SHARD = 120
BUILD_TIMEOUT_S = 300  # a deadlocked pipeline never finishes; a healthy one takes ~1 min here


_TOKEN = secrets.token_hex(32)


def _env() -> dict:
    """No proxies (the fake LLM is on 127.0.0.1), this tree on the path, and one Ray
    authentication token shared by the test's cluster nodes and drivers."""
    env = {k: v for k, v in os.environ.items() if "proxy" not in k.lower()}
    env["PYTHONPATH"] = str(REPO)
    env.pop("RAY_ADDRESS", None)
    env.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=_TOKEN)
    return env


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "ratouch.cli", "corpus", "build", "--engine", "ray", *args]


def _run(cmd: list[str], timeout: float = BUILD_TIMEOUT_S) -> dict:
    """Run a build in its own process group; kill the whole group on timeout."""
    p = subprocess.Popen(cmd, cwd=REPO, env=_env(), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        pytest.fail(f"the Ray build did not finish in {timeout} s (deadlock?)")
    assert p.returncode == 0, err[-3000:]
    return json.loads(out.strip().splitlines()[-1])


def _assert_same_corpus(a: Path, b: Path) -> None:
    ma, ea = load_corpus(a)
    mb, eb = load_corpus(b)
    assert [(e.id, e.caption, e.source, e.class_name) for e in ea] == \
        [(e.id, e.caption, e.source, e.class_name) for e in eb]
    assert ma["metadata_sha256"] == mb["metadata_sha256"]
    ia, ta, _ = load_embeddings(a, "default-s")
    ib, tb, _ = load_embeddings(b, "default-s")
    np.testing.assert_allclose(ia, ib, atol=1e-5)
    np.testing.assert_allclose(ta, tb, atol=1e-5)


def _assert_listed_shards_valid(folder: Path) -> None:
    """Every shard the manifest lists as finished is there with matching checksums."""
    shards = folder / SHARD_DIR
    manifest = json.loads((shards / "manifest.json").read_text())
    for s, rec in manifest["shards"].items():
        for kind, sha in rec["sha256"].items():
            assert sha256_file(shards / f"shard-{int(s):05d}.{kind}") == sha


def _assert_clean_shards(folder: Path) -> None:
    """Every shard file is listed in the manifest with a matching checksum; nothing partial."""
    shards = folder / SHARD_DIR
    manifest = json.loads((shards / "manifest.json").read_text())
    listed = {}
    for s, rec in manifest["shards"].items():
        for kind, sha in rec["sha256"].items():
            listed[f"shard-{int(s):05d}.{kind}"] = sha
    on_disk = {p.name for p in shards.iterdir()} - {"manifest.json"}
    assert on_disk <= set(listed), f"unlisted files: {on_disk - set(listed)}"
    for name in on_disk:
        assert sha256_file(shards / name) == listed[name], name
    assert not list(folder.rglob("*partial*"))


@pytest.fixture(scope="module")
def single(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("single") / "c"
    build_corpus(folder, N, seed=0, progress=False)
    embed_and_index(folder, "default-s", workers=1, progress=False)
    return folder


@pytest.fixture(scope="module")
def ray_two_cores(tmp_path_factory) -> tuple[Path, dict, dict]:
    """A Ray build on a local Ray of exactly 2 CPUs, killed once its first shard is finished,
    then run again to the end with 2 embedding actors (the set-up that hangs when the actors
    take a whole core each): one build serves the kill's tests and the finished corpus's (a
    local Ray costs about 25 s to start here). Returns the corpus folder, the finishing run's
    report and what was seen at the kill."""
    folder = tmp_path_factory.mktemp("ray") / "c"
    args = ["--out", str(folder), "--size", str(N), "--num-cpus", "2", "--batch-size", "60",
            "--shard-size", str(SHARD)]
    # one actor until the kill: with two, all three shards can finish before it lands
    p = subprocess.Popen(_cli(*args, "--workers", "1"), cwd=REPO, env=_env(),
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True)
    manifest = folder / SHARD_DIR / "manifest.json"
    deadline = time.monotonic() + BUILD_TIMEOUT_S
    while time.monotonic() < deadline and p.poll() is None:
        if manifest.is_file() and json.loads(manifest.read_text())["shards"]:
            break
        time.sleep(0.2)
    assert p.poll() is None, "the build ended before it could be killed"
    ours = [pid for pid, tag in tagged().items() if tag.startswith(f"{p.pid}-")]
    os.kill(p.pid, signal.SIGKILL)  # the driver alone, as `kill -9 PID` does
    p.wait()
    # its reaper ends the local Ray: no ray::DashboardAgent / RuntimeEnvAgent left behind
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and any(_running(q) for q in ours):
        time.sleep(0.2)
    killed = {"tagged": len(ours),
              "left": [psutil.Process(q).name() for q in ours if _running(q)],
              "done": set(json.loads(manifest.read_text())["shards"]),
              "corpus_there": (folder / "metadata.jsonl").exists()}
    _assert_listed_shards_valid(folder)
    return folder, _run(_cli(*args, "--workers", "2")), killed


def test_actor_cpus_leave_room_for_the_light_stages():
    per = plan_cpus(2, 2)
    assert per == 0.75 and 2 * per + 2 * 0.25 <= 2
    assert plan_cpus(16, 4) == 1.0
    assert plan_cpus(2, 2, llm_actors=2) + 0.25 * 4 <= 2 / 2 * 2
    with pytest.raises(ConfigError, match="workers=40"):
        plan_cpus(2, 40)


def test_ray_build_finishes_on_two_cores_and_matches_the_single_process_build(
        ray_two_cores, single):
    folder, r, killed = ray_two_cores
    assert r["size"] == N and r["shards"] == 3 and r["shards_built"] == 3 - len(killed["done"])
    assert {"plan", "recaption", "render", "embed", "write", "index"} <= set(r["stages"])
    _assert_same_corpus(single, folder)
    _assert_clean_shards(folder)


def test_the_pipeline_opens_a_ray_built_corpus_unchanged(ray_two_cores):
    folder, _, _ = ray_two_cores
    search = open_retriever(folder, "default-s")
    _, entries = load_corpus(folder)
    q = load_embeddings(folder, "default-s")[0][:3]
    got = search.retrieve({"image": np.asarray(q)}, k=1, settings=["image_image"])
    assert got["image_image"][1][:, 0].tolist() == [0, 1, 2]
    assert len(search.corpus) == len(entries) == N


def test_rerun_skips_finished_shards_and_refuses_another_build(ray_two_cores):
    """A re-run finds every shard finished (no Ray needed) and only adds what is missing:
    here an IVF index built from the shards as one on-disk index, which the retriever opens
    unchanged."""
    folder, _, _ = ray_two_cores
    r = _run(_cli("--out", str(folder), "--size", str(N), "--shard-size", str(SHARD),
                  "--index", "ivfflat"), 120)
    assert r["shards_built"] == 0 and r["size"] == N
    assert (folder / "index" / "default-s" / "text-ivfflat" / "lists.ivfdata").is_file()
    search = open_retriever(folder, "default-s", "ivfflat")
    q = np.asarray(load_embeddings(folder, "default-s")[1][:20])
    ids = search.corpus.search("text", q, 5)[1]
    assert np.mean([i in row for i, row in enumerate(ids)]) >= 0.9  # itself among its top 5
    p = subprocess.run(_cli("--out", str(folder), "--size", str(N), "--seed", "1",
                            "--shard-size", str(SHARD)), cwd=REPO, env=_env(),
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "shards of another build" in p.stderr


def test_killed_build_resumes_with_finished_shards_kept(ray_two_cores, single):
    """The whole build (driver and its local Ray) is killed once a shard is finished; the
    finished shards stay valid (checked at the kill), nothing partial is visible, and a
    re-run completes the corpus, building only the missing shards."""
    folder, r, killed = ray_two_cores
    assert killed["tagged"] >= 3, "the build's local Ray processes carry its tag"
    assert not killed["left"], f"the killed build left {killed['left']} running"
    assert 1 <= len(killed["done"]) < 3
    assert not killed["corpus_there"]  # the corpus is not there half-made
    assert r["shards_built"] == 3 - len(killed["done"])
    _assert_same_corpus(single, folder)
    _assert_clean_shards(folder)


def test_reindex_rebuilds_a_corrupt_index_on_ray_as_locally(ray_two_cores):
    """An index refused as corrupt names `--reindex`; with it, the Ray engine removes the
    index and builds it again from the finished shards (no Ray needed), as the local engine
    does."""
    folder, _, _ = ray_two_cores
    index = folder / "index" / "default-s" / "text-flat" / "index.faiss"
    good = index.read_bytes()
    index.write_bytes(good[: len(good) // 2])
    args = ["--out", str(folder), "--size", str(N), "--shard-size", str(SHARD)]
    p = subprocess.run(_cli(*args), cwd=REPO, env=_env(), capture_output=True, text=True,
                       timeout=BUILD_TIMEOUT_S)
    assert p.returncode != 0 and "--reindex" in p.stderr
    r = _run(_cli(*args, "--reindex"), BUILD_TIMEOUT_S)
    assert r["shards_built"] == 0 and index.read_bytes() == good
    open_retriever(folder, "default-s")


# ---------------------------------------------------------------------------------------------
# a real local cluster: `ray start --head` + one worker node

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ray_cluster():
    """A head node and one worker node on 127.0.0.1, one CPU each, stopped by process group
    (nothing of either left running: checked when the module ends)."""
    port = _free_port()
    address = f"127.0.0.1:{port}"
    ray_bin = str(Path(sys.executable).with_name("ray"))
    common = ["--num-cpus", "1", "--block", "--disable-usage-stats"]
    head = subprocess.Popen([ray_bin, "start", "--head", "--node-ip-address", "127.0.0.1",
                             "--port", str(port), "--include-dashboard", "false", *common],
                            env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    procs = [head]
    try:
        time.sleep(8)
        worker = subprocess.Popen([ray_bin, "start", "--address", address,
                                   "--node-ip-address", "127.0.0.1", *common], env=_env(),
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                  start_new_session=True)
        procs.append(worker)
        _wait_for_nodes(address, 2)
        yield address
    finally:
        # a node asked to stop takes 13-20 s to wind down (33 s of the module's time); its
        # processes are all in its group, so what has not ended within 3 s is killed with it
        for p in reversed(procs):
            with_group(p, signal.SIGTERM)
        for p in reversed(procs):
            try:
                p.wait(3)
            except subprocess.TimeoutExpired:
                with_group(p, signal.SIGKILL)
                p.wait(20)
        groups = {p.pid for p in procs}
        deadline = time.monotonic() + 10  # killed processes are reaped by init: a moment
        while (left := _in_groups(groups)) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not left, f"the test cluster left {left} running"


def _in_groups(groups: set[int]) -> list[str]:
    """Names of the running (not zombie: `_running`) processes in these process groups."""
    found = []
    for q in psutil.process_iter(["name"]):
        try:
            if _running(q.pid) and os.getpgid(q.pid) in groups:
                found.append(q.info["name"])
        except ProcessLookupError:  # ended meanwhile
            pass
    return found


def with_group(p: subprocess.Popen, sig: int) -> None:
    try:
        os.killpg(p.pid, sig)
    except ProcessLookupError:
        pass


def _wait_for_nodes(address: str, n: int, timeout: float = 90) -> None:
    code = ("import ray,sys; ray.init(address=sys.argv[1], logging_level='ERROR'); "
            "print(sum(1 for x in ray.nodes() if x['Alive']))")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        p = subprocess.run([sys.executable, "-c", code, address], env=_env(),
                           capture_output=True, text=True, timeout=60)
        if p.returncode == 0 and int(p.stdout.strip().splitlines()[-1]) >= n:
            return
        time.sleep(2)
    pytest.fail(f"the Ray cluster at {address} did not come up with {n} nodes")


@pytest.mark.slow
def test_llm_stage_on_a_cluster_with_per_entry_fallback(ray_cluster, tmp_path, monkeypatch):
    """A --from-list corpus recaptioned by the fake LLM on a 2-node cluster: the classes it
    knows get its caption, the class it fails on gets the offline caption (after retries)."""
    rows = []
    for i in range(24):
        cls = ("pan", "bear", "rock", "sponge")[i % 4]
        path = tmp_path / f"img{i}.png"
        Image.fromarray(np.full((32, 32, 3), 40 * (i % 6), np.uint8)).save(path)
        rows.append(f"{path.name},{cls},a {cls} on a table")
    lst = tmp_path / "list.csv"
    lst.write_text("path,class,caption\n" + "\n".join(rows) + "\n")
    with serve_fake_llm(monkeypatch, "unused") as llm:
        llm.mode = "echo"  # answers by class; fails (no reply) on "sponge"
        r = _run(_cli("--out", str(tmp_path / "c"), "--size", "24", "--from-list", str(lst),
                      "--captioner", "llm", "--endpoint", llm.endpoint, "--address",
                      ray_cluster, "--workers", "1", "--batch-size", "8", "--shard-size", "10",
                      "--llm-concurrency", "3", "--llm-rate", "200"))
    _, entries = load_corpus(tmp_path / "c")
    offline = OfflineRecaptioner(world_lexicon())
    echo = {"pan": "hard, metallic, smooth, rigid, solid",
            "bear": "soft, furry, plush, fluffy, cushioned",
            "rock": "rough, hard, craggy, uneven, gritty"}
    for e in entries:
        want = echo.get(e.class_name) or ", ".join(offline.recaption(e.class_name,
                                                                     e.description))
        assert e.caption == want, e
    assert r["captioner_stats"]["n_fallbacks"] == 6
    assert r["captioner_stats"]["n_requests"] == 18 + 6 * 2  # 2 attempts before falling back


@pytest.mark.slow
def test_worker_killed_mid_build_loses_nothing(ray_cluster, tmp_path, single):
    """An embedding actor's process is killed once a shard is finished: Ray restarts it, the
    build completes with the same corpus, and no shard is lost or left partial."""
    folder = tmp_path / "c"
    cmd = _cli("--out", str(folder), "--size", str(N), "--address", ray_cluster, "--workers",
               "2", "--batch-size", "40", "--shard-size", str(SHARD))
    p = subprocess.Popen(cmd, cwd=REPO, env=_env(), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    manifest = folder / SHARD_DIR / "manifest.json"
    killed = None
    deadline = time.monotonic() + BUILD_TIMEOUT_S
    while killed is None and time.monotonic() < deadline and p.poll() is None:
        if manifest.is_file() and json.loads(manifest.read_text())["shards"]:
            for proc in psutil.process_iter(["pid", "cmdline"]):
                if "EmbedStage" in " ".join(proc.info["cmdline"] or []):
                    proc.kill()
                    killed = proc.info["pid"]
                    break
        time.sleep(0.1)
    assert killed is not None, "no embedding actor was found to kill"
    out, err = p.communicate(timeout=BUILD_TIMEOUT_S)
    assert p.returncode == 0, err[-3000:]
    assert json.loads(out.strip().splitlines()[-1])["size"] == N
    _assert_same_corpus(single, folder)
    _assert_clean_shards(folder)


@pytest.mark.slow
def test_two_thousand_entries_same_either_way(tmp_path):
    """The issue's 2k-entry comparison: Ray build (local Ray, 2 actors) against the
    single-process build."""
    a, b = tmp_path / "single", tmp_path / "ray"
    build_corpus(a, 2000, seed=0, progress=False)
    embed_and_index(a, "default-s", workers=2, progress=False)
    r = _run(_cli("--out", str(b), "--size", "2000", "--workers", "2"), 600)
    assert r["size"] == 2000 and r["shards"] == 2
    _assert_same_corpus(a, b)
    _assert_clean_shards(b)
