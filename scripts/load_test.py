"""Load test of the app with the real default pipeline, as a user would start it.

Launches `python -m app --port P` on 127.0.0.1 and measures:

1. time to ready: from launch until the HTTP endpoint answers, and until the first `/query`
   is answered (the models load in the background, so the second is later);
2. single-user latency: sequential `/query` calls, p50;
3. under load: N concurrent clients x M queries each, p50 / p95, queries/s and failures, and
   the CPU seconds per query of the server, of the clients and of everything else;
4. the server's RSS (psutil, with its child processes) before and after the load, and the
   machine's load average while it ran.

The load comes from this one process: each client is a thread with its own keep-alive HTTP
connection speaking Gradio's REST API (upload both images, call `/query`, read the answer's
event stream) with the standard library, so the clients take little of the CPU the server
needs (gradio_client took more CPU per query than the server did).

Before any query, the script reads the `/query` endpoint's inputs from the running app
(``/gradio_api/info``, what gradio_client's `view_api` reads) and stops with a clear message
when they are not the ones it sends (`INPUTS`): an input added to the API must be added here.
Every answer is checked (`RESULT_KEYS`, K neighbours, a description); a query that errors or
answers incompletely is counted as a failure, by kind, and the script exits non-zero.

Targets (reported, checked with --check): HTTP-ready <= 15 s; single-user p50 <= 120 ms;
>= 15 queries/s under load, p95 <= 1.5 s, <= 50 ms of server CPU per query, no failures.
Bounded in time: queries still waiting at --deadline are counted as not run, and the whole run
stops at --timeout.

    .venv/bin/python scripts/load_test.py [--clients 16] [--queries 10] [--warm-load N]
        [--model-processes N] [--json out.json]

--warm-load N: each client first sends N queries that are not counted, so that the load
measured is the one a server settles into (its model processes started and loaded).

Exit status: 0; 1 when a query failed, the endpoint's inputs changed, the app did not come up
or (--check) a target was missed.
"""

from __future__ import annotations

import argparse
import collections
import http.client
import json
import os
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
import uuid
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
READY_TARGET_S = 15.0
SINGLE_P50_TARGET_S = 0.120
QPS_TARGET = 15.0
LOAD_P95_TARGET_S = 1.5
SERVER_CPU_TARGET_S = 0.050
PAIRS = (60, 140, 190, 290, 12, 390, 75, 333)  # test-split pairs the clients send, in turn
ENDPOINT = "query"
# The `/query` endpoint's inputs, in order, as the app describes them: (parameter name,
# component). `ApiClient.values` fills them; the app's inputs must be exactly these.
INPUTS = (("visual", "File"), ("tactile", "File"), ("a", "Textbox"), ("b", "Textbox"),
          ("c", "Textbox"), ("d", "Textbox"), ("k", "Slider"), ("model", "Dropdown"),
          ("background", "File"), ("retrieval", "Dropdown"))
RESULT_KEYS = ("neighbours", "description", "timings_ms", "warnings", "box")  # of every answer
NO_MESSAGE = ("the server answered with an error event without a message (the app hides "
              "error details: show_error=False); the server log says why")


class LoadTestError(RuntimeError):
    """The load test cannot run: the app did not come up, its `/query` endpoint takes other
    inputs than this script sends, a warm-up query failed, or the time ran out."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


Upload = tuple[str, bytes]  # a file as a client uploads it: its name and bytes


def write_pairs(folder: Path) -> list[tuple[Upload, Upload, list[int], Upload]]:
    """Test-split pairs as PNG files (what a client uploads: name and bytes): (visual,
    tactile, contact box, the tactile sensor's background), as a TVL row carries them."""
    from PIL import Image

    from ratouch.world.sampler import World

    world, out = World(), []
    for i in PAIRS:
        s = world.sample("test", i)
        v, t = folder / f"visual_{i}.png", folder / f"tactile_{i}.png"
        b = folder / f"background_{i}.png"
        Image.fromarray(s.visual).save(v)
        Image.fromarray(s.tactile).save(t)
        Image.fromarray(world.background_image(s.sensor)).save(b)
        out.append(((v.name, v.read_bytes()), (t.name, t.read_bytes()),
                    [int(x) for x in s.box], (b.name, b.read_bytes())))
    return out


def rss_mib(pid: int) -> float:
    import psutil

    p = psutil.Process(pid)
    procs = [p, *p.children(recursive=True)]
    total = 0
    for q in procs:
        try:
            total += q.memory_info().rss
        except psutil.Error:
            pass
    return round(total / 2**20, 1)


def cpu_s(pid: int, children: bool = True) -> float:
    """User + system CPU seconds of a process (and its children)."""
    import psutil

    p = psutil.Process(pid)
    total = 0.0
    for q in [p, *(p.children(recursive=True) if children else [])]:
        try:
            t = q.cpu_times()
            total += t.user + t.system
        except psutil.Error:
            pass
    return total


def busy_s() -> float:
    """CPU seconds the whole machine has been busy (all cores)."""
    import psutil

    t = psutil.cpu_times()
    return sum(t) - t.idle - getattr(t, "iowait", 0.0)


def wait_http(url: str, proc: subprocess.Popen, timeout: float) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise RuntimeError(f"the app exited with code {proc.returncode} before answering")
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                if r.status == 200:
                    return
        except OSError:
            pass
        time.sleep(0.1)
    raise RuntimeError(f"{url} did not answer within {timeout:.0f} s")


def endpoint_inputs(port: int, timeout: float = 30.0) -> list[dict]:
    """The `/query` endpoint's parameters as the running app describes them (GET
    ``/gradio_api/info``, what gradio_client's `view_api` reads), in order.

    Raises:
        LoadTestError: the app has no `/query` endpoint.
    """
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/gradio_api/info",
                                timeout=timeout) as r:
        info = json.load(r)
    named = info.get("named_endpoints") or {}
    if f"/{ENDPOINT}" not in named:
        raise LoadTestError(f"the app has no /{ENDPOINT} endpoint (its API: {sorted(named)})")
    return named[f"/{ENDPOINT}"]["parameters"]


def check_inputs(params: list[dict]) -> None:
    """Raise LoadTestError, naming both lists, unless the endpoint's inputs are `INPUTS`."""
    got = [(p.get("parameter_name"), p.get("component")) for p in params]
    if got != [tuple(x) for x in INPUTS]:
        def names(items) -> str:
            return ", ".join(f"{n} ({c})" for n, c in items)

        described = "; ".join(f"{p.get('parameter_name')}: {p.get('component')} "
                              f"{p.get('label')!r}" for p in params)
        raise LoadTestError(
            f"the app's /{ENDPOINT} endpoint takes {len(got)} inputs [{names(got)}] but this "
            f"script sends {len(INPUTS)} [{names(INPUTS)}]; update INPUTS and "
            f"ApiClient.values in scripts/load_test.py (the endpoint's inputs: {described})")


def choose_model(params: list[dict], wanted: str | None = None) -> str:
    """The model the queries name: `wanted`, else the endpoint's default (the app's).

    Raises:
        LoadTestError: `wanted` is not one the endpoint offers.
    """
    p = next(p for p in params if p.get("parameter_name") == "model")
    kind = str((p.get("python_type") or {}).get("type", ""))
    offered = re.findall(r"'([^']*)'", kind) if kind.startswith("Literal[") else []
    model = p.get("parameter_default") if wanted is None else wanted
    model = "" if model is None else str(model)
    if offered and model not in offered:
        raise LoadTestError(f"model {model!r} is not offered by the app's /{ENDPOINT} "
                            f"endpoint (it offers {offered})")
    return model


def error_message(data: str) -> str:
    """What an error event of the answer's stream says: Gradio sends {"error": message}, with
    message null when the app hides its errors (`NO_MESSAGE` then, never "null")."""
    try:
        message = json.loads(data) if data else None
    except ValueError:
        message = data
    if isinstance(message, dict):
        message = message.get("error")
    return str(message)[:200] if message else NO_MESSAGE


def check_answer(out: object, k: int) -> dict:
    """`out` if it is a whole answer (`RESULT_KEYS`, K joint neighbours, a RA-Touch
    description), else a RuntimeError naming what is missing."""
    if not isinstance(out, dict):
        raise RuntimeError(f"the answer is a {type(out).__name__}, not an object: "
                           f"{str(out)[:200]}")
    missing = [key for key in RESULT_KEYS if key not in out]
    if missing:
        raise RuntimeError(f"the answer lacks {missing} (it has {sorted(out)})")
    if len(out["neighbours"].get("joint", [])) != k or not out["description"].get("ra_touch"):
        raise RuntimeError(f"incomplete answer: {str(out)[:200]}")
    return out


class ApiClient:
    """One user of the `/query` API over a keep-alive HTTP connection (Gradio's REST API:
    POST gradio_api/upload, POST gradio_api/call/query, GET its event stream).

    Args:
        inputs: the endpoint's parameter names, in order (`endpoint_inputs`).
        model: the model every query names.
        session: keep one Gradio session for all this client's queries (its own session
            hash, as gradio_client and a browser tab keep one); False: send none, so that the
            app opens a new session for every query.
    """

    def __init__(self, port: int, timeout: float = 120.0,
                 inputs: tuple[str, ...] = tuple(n for n, _ in INPUTS), model: str = "",
                 session: bool = True):
        self.conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
        self.inputs, self.model = tuple(inputs), model
        self.session_hash = uuid.uuid4().hex[:12] if session else None

    def _request(self, method: str, path: str, body: bytes | None = None,
                 headers: dict | None = None) -> http.client.HTTPResponse:
        for attempt in (0, 1):  # a keep-alive connection the server closed: reconnect once
            try:
                self.conn.request(method, path, body=body, headers=headers or {})
                return self.conn.getresponse()
            except (http.client.RemoteDisconnected, ConnectionResetError, BrokenPipeError):
                self.conn.close()
                if attempt:
                    raise
        raise AssertionError("not reached")

    def _json(self, method: str, path: str, body: bytes, headers: dict):
        r = self._request(method, path, body, headers)
        data = r.read()
        if r.status != 200:
            raise RuntimeError(f"{path}: HTTP {r.status}: {data[:200]!r}")
        return json.loads(data)

    def upload(self, files: list[tuple[str, bytes]]) -> list[str]:
        """Server paths of the uploaded (name, bytes) files."""
        boundary = "ratouch-load-test-boundary"
        parts = [b"".join([f"--{boundary}\r\nContent-Disposition: form-data; name=\"files\"; "
                           f"filename=\"{name}\"\r\nContent-Type: image/png\r\n\r\n".encode(),
                           data, b"\r\n"]) for name, data in files]
        body = b"".join(parts) + f"--{boundary}--\r\n".encode()
        return self._json("POST", "/gradio_api/upload", body,
                          {"Content-Type": f"multipart/form-data; boundary={boundary}"})

    def values(self, visual: dict, tactile: dict, box, k: int,
               background: dict | None = None) -> list:
        """The endpoint's inputs, in its order: the uploaded files, the box as the four text
        fields (x0, y0, x1, y1), K, the model, the sensor's background (or None) and the
        retrieval system (None: the app's default)."""
        by_name = {"visual": visual, "tactile": tactile, "k": k, "model": self.model,
                   "background": background, "retrieval": None,
                   **{n: str(int(v)) for n, v in zip("abcd", box)}}
        unknown = [n for n in self.inputs if n not in by_name]
        if unknown:
            raise LoadTestError(f"this script does not know how to fill the /{ENDPOINT} "
                                f"inputs {unknown}")
        return [by_name[n] for n in self.inputs]

    def query(self, visual: Upload, tactile: Upload, box, k: int,
              deadline: float | None = None, background: Upload | None = None) -> dict:
        """`/query` with freshly uploaded images (the sensor's background too, when given),
        as a user's call would make it; gives up (TimeoutError) at `deadline`
        (time.monotonic())."""
        uploads = [visual, tactile] + ([background] if background is not None else [])
        paths = self.upload(uploads)
        files = [{"path": p, "orig_name": n, "meta": {"_type": "gradio.FileData"}}
                 for p, (n, _) in zip(paths, uploads, strict=True)]
        data = self.values(files[0], files[1], box, k, files[2] if background else None)
        body: dict = {"data": data}
        if self.session_hash is not None:
            body["session_hash"] = self.session_hash
        event = self._json("POST", f"/gradio_api/call/{ENDPOINT}", json.dumps(body).encode(),
                           {"Content-Type": "application/json"})["event_id"]
        r = self._request("GET", f"/gradio_api/call/{ENDPOINT}/{event}")
        kind = None
        try:
            for raw in iter(r.readline, b""):
                if deadline is not None and time.monotonic() > deadline:
                    self.conn.close()  # the stream is abandoned: not reusable
                    raise TimeoutError(f"/{ENDPOINT}: no answer before the deadline")
                line = raw.decode().strip()
                if line.startswith("event:"):
                    kind = line[6:].strip()
                elif line.startswith("data:") and kind in ("complete", "error"):
                    data = line[5:].strip()
                    if kind == "error":
                        raise RuntimeError(f"/{ENDPOINT} failed: {error_message(data)}")
                    return check_answer((json.loads(data) or [None])[0], k)
        finally:
            if not r.isclosed():
                r.read()  # drain, so the connection can be reused
        raise RuntimeError(f"/{ENDPOINT}: the event stream ended without an answer "
                           f"(last event {kind})")


class LoadAverage(threading.Thread):
    """Samples os.getloadavg()[0] every second while the load runs."""

    def __init__(self):
        super().__init__(daemon=True)
        self.samples: list[float] = []
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            self.samples.append(os.getloadavg()[0])
            self.stop.wait(1.0)


def percentiles(xs: list[float]) -> dict:
    if not xs:
        return {"n": 0}
    p50, p95 = np.percentile(xs, [50, 95])
    return {"n": len(xs), "p50_s": round(float(p50), 3), "p95_s": round(float(p95), 3),
            "mean_s": round(float(np.mean(xs)), 3), "max_s": round(float(max(xs)), 3)}


def run(clients: int = 16, queries: int = 10, single: int = 8, k: int = 5,
        deadline_s: float = 120.0, app_args: tuple[str, ...] = (), env: dict | None = None,
        log=print, model: str | None = None, timeout_s: float = 900.0,
        sessions: str = "client", warm_load: int = 0) -> dict:
    """Launch the app, measure, stop it. Returns the report (a JSON-ready dict).

    Args:
        deadline_s: longest load phase: queries not sent by then are counted as not run.
        app_args: extra `python -m app` arguments.
        env: the app's environment (default: this process's).
        model: the model every query names (default: the app's default one).
        timeout_s: longest whole run, launch to report (a query still waiting then fails).
        sessions: "client": each client keeps one Gradio session for its queries (as a
            browser tab or gradio_client does); "query": every query opens a new one (the app
            then builds a session's state per query).
        warm_load: queries each client sends at once before the measured load, not counted
            (what a server settles into under load: its model processes started, say).

    Raises:
        LoadTestError: the app did not come up, its `/query` endpoint takes other inputs than
            `INPUTS`, a warm-up or single-user query failed, or the time ran out before the load.

    Long on purpose: a script's measurement in the order it happens (launch, warm-up, one user,
    the load, the report), each phase timed where it runs.
    """
    t_start = time.monotonic()
    t_end = t_start + timeout_s
    port = free_port()
    url = f"http://127.0.0.1:{port}/"
    if sessions not in ("client", "query"):
        raise LoadTestError(f"sessions={sessions!r}: 'client' or 'query'")
    report: dict = {"clients": clients, "queries_per_client": queries, "k": k,
                    "sessions": f"one per {sessions}",
                    "app_args": list(app_args),
                    "cpus": os.cpu_count(), "loadavg_before": [round(x, 2) for x in
                                                                 os.getloadavg()]}

    def left(cap: float) -> float:
        """Seconds to wait: at most `cap`, and never past the run's end."""
        rest = t_end - time.monotonic()
        if rest <= 0:
            raise LoadTestError(f"the load test did not finish within --timeout {timeout_s:.0f} s")
        return min(cap, rest)

    with tempfile.TemporaryDirectory(prefix="ratouch-load-") as tmp:
        pairs = write_pairs(Path(tmp))
        server_log = open(Path(tmp) / "server.log", "w")
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "app", "--host", "127.0.0.1",
                                 "--port", str(port), *app_args], cwd=REPO, env=env,
                                stdout=server_log, stderr=subprocess.STDOUT)
        try:
            try:
                wait_http(url, proc, timeout=left(120))
            except RuntimeError as e:
                raise LoadTestError(str(e)) from e
            report["ready_http_s"] = round(time.monotonic() - t0, 2)
            log(f"HTTP endpoint answers {report['ready_http_s']} s after launch")
            try:
                params = endpoint_inputs(port, timeout=left(30))
            except (OSError, ValueError, KeyError) as e:
                raise LoadTestError(f"cannot read the app's API description "
                                    f"(/gradio_api/info): {type(e).__name__}: {e}") from e
            check_inputs(params)  # before any query: a changed API stops the test here
            report["endpoint_inputs"] = [p["parameter_name"] for p in params]
            report["model"] = choose_model(params, model)
            log(f"/{ENDPOINT} takes {report['endpoint_inputs']}; the queries name model "
                f"{report['model']!r}")

            def connect() -> ApiClient:
                return ApiClient(port, timeout=left(120), inputs=report["endpoint_inputs"],
                                 model=report["model"], session=sessions == "client")

            def ask(c: ApiClient, j: int) -> float:
                v, t, box, bg = pairs[j % len(pairs)]
                t1 = time.monotonic()
                out = c.query(v, t, box, k, deadline=t_end, background=bg)
                with lock:
                    server.append((out["timings_ms"]["total"] / 1000,
                                   out["timings_ms"].get("batch_size", 1)))
                return time.monotonic() - t1

            def ask_or_stop(c: ApiClient, j: int, what: str) -> float:
                try:
                    return ask(c, j)
                except LoadTestError:
                    raise
                except Exception as e:  # noqa: BLE001 - the run cannot go on: say why
                    raise LoadTestError(f"{what} failed: {type(e).__name__}: {e}") from e

            lock = threading.Lock()
            server: list[tuple[float, int]] = []  # (pipeline seconds, batch size) per answer
            client = connect()
            ask_or_stop(client, 0, "the first /query (waiting for the models)")
            report["ready_query_s"] = round(time.monotonic() - t0, 2)
            log(f"first /query answered {report['ready_query_s']} s after launch")
            solo = [ask_or_stop(client, j, f"single-user /query {j}")
                    for j in range(1, single + 1)]
            report["single"] = percentiles(solo)
            if solo:
                report["single"]["pipeline_mean_s"] = round(float(np.mean(
                    [t for t, _ in server[-single:]])), 3)
            log(f"single user: {report['single']}")
            report["rss_before_mib"] = rss_mib(proc.pid)

            latencies: list[float] = []
            failures: collections.Counter[str] = collections.Counter()  # kind -> queries
            not_run = [0]
            n_solo = len(server)

            def client_run(ci: int) -> None:
                try:
                    c = connect()
                except LoadTestError:  # no time left for this client
                    with lock:
                        not_run[0] += queries
                    return
                for q in range(queries):
                    if time.monotonic() > stop_at:
                        with lock:
                            not_run[0] += queries - q
                        return
                    try:
                        dt = ask(c, ci + q)
                        with lock:
                            latencies.append(dt)
                    except Exception as e:  # noqa: BLE001 - counted and reported
                        with lock:
                            failures[f"{type(e).__name__}: {str(e)[:200]}"] += 1

            if warm_load > 0:
                t_warm = time.monotonic()
                warm_failed = [0]

                def warm_run(ci: int) -> None:
                    try:
                        c = connect()
                        for q in range(warm_load):
                            ask(c, ci + q)
                    except Exception:  # noqa: BLE001 - counted, not measured
                        with lock:
                            warm_failed[0] += 1

                warm = [threading.Thread(target=warm_run, args=(i,), daemon=True)
                        for i in range(clients)]
                for th in warm:
                    th.start()
                for th in warm:
                    th.join(timeout=max(1.0, t_end - time.monotonic()))
                report["warm_load"] = {"queries": clients * warm_load,
                                       "wall_s": round(time.monotonic() - t_warm, 1),
                                       "clients_failed": warm_failed[0]}
                log(f"warm-up load (not counted): {report['warm_load']}")
                report["rss_before_mib"] = rss_mib(proc.pid)

            loadavg = LoadAverage()
            loadavg.start()
            cpu0 = (cpu_s(proc.pid), cpu_s(os.getpid(), children=False), busy_s())
            t_load = time.monotonic()
            stop_at = min(t_load + deadline_s, t_end)
            threads = [threading.Thread(target=client_run, args=(i,), daemon=True)
                       for i in range(clients)]
            for th in threads:
                th.start()
            for th in threads:  # a query in flight at the end has until t_end to answer
                th.join(timeout=max(1.0, min(stop_at + 60, t_end + 5) - time.monotonic()))
            loadavg.stop.set()
            report["load_wall_s"] = round(time.monotonic() - t_load, 1)
            stuck = sum(th.is_alive() for th in threads)
            if stuck:  # a query still unanswered at the end is a failure, not silence
                with lock:
                    failures["TimeoutError: no answer by the end of the run"] += stuck
            n_done = max(1, len(latencies) + sum(failures.values()))
            report["cpu_s_per_query"] = {  # where the machine's time went under load
                "server": round((cpu_s(proc.pid) - cpu0[0]) / n_done, 3),
                "clients": round((cpu_s(os.getpid(), children=False) - cpu0[1]) / n_done, 3)}
            busy = busy_s() - cpu0[2]  # every process on the machine
            report["machine_busy"] = round(busy / (report["load_wall_s"] * (os.cpu_count() or 1)),
                                           2)
            report["cpu_s_per_query"]["other processes"] = round(
                busy / n_done - sum(report["cpu_s_per_query"].values()), 3)
            report["under_load"] = percentiles(latencies)
            loaded = server[n_solo:]
            if loaded:  # what the pipeline itself took, and how full its batches were
                report["under_load"]["pipeline_mean_s"] = round(float(np.mean(
                    [t for t, _ in loaded])), 3)
                report["under_load"]["mean_batch"] = round(float(np.mean(
                    [b for _, b in loaded])), 2)
            report["throughput_qps"] = round(len(latencies) / report["load_wall_s"], 2)
            with lock:
                report["answered"] = len(latencies)
                report["failures"] = sum(failures.values())
                # kind of failure -> how many queries failed so
                report["failure_kinds"] = dict(failures.most_common())
                report["not_run"] = not_run[0]
            report["failure_examples"] = list(report["failure_kinds"])[:5]
            report["rss_after_mib"] = rss_mib(proc.pid)
            report["loadavg_during"] = {
                "mean": round(float(np.mean(loadavg.samples)), 2),
                "max": round(float(max(loadavg.samples)), 2)} if loadavg.samples else None
        except LoadTestError as e:
            e.server_log = _tail(proc, server_log, Path(tmp) / "server.log")
            raise
        finally:
            report["server_log_tail"] = _tail(proc, server_log, Path(tmp) / "server.log")
    single_p50 = report.get("single", {}).get("p50_s")
    load_p50 = report.get("under_load", {}).get("p50_s")
    report["ratio_p50"] = round(load_p50 / single_p50, 2) if single_p50 and load_p50 else None
    report["targets"] = {
        f"ready_http <= {READY_TARGET_S:.0f} s": report.get("ready_http_s", 1e9) <= READY_TARGET_S,
        f"single-user p50 <= {SINGLE_P50_TARGET_S * 1000:.0f} ms":
            (single_p50 or 1e9) <= SINGLE_P50_TARGET_S,
        f">= {QPS_TARGET:.0f} queries/s under load": report.get("throughput_qps", 0) >= QPS_TARGET,
        f"p95 under load <= {LOAD_P95_TARGET_S} s":
            report.get("under_load", {}).get("p95_s", 1e9) <= LOAD_P95_TARGET_S,
        f"server CPU <= {SERVER_CPU_TARGET_S * 1000:.0f} ms per query":
            report.get("cpu_s_per_query", {}).get("server", 1e9) <= SERVER_CPU_TARGET_S,
        "no failures": report.get("failures", 1) == 0 and report.get("not_run", 1) == 0}
    report["total_s"] = round(time.monotonic() - t_start, 1)
    return report


def _tail(proc: subprocess.Popen, log_file, path: Path, lines: int = 8) -> list[str]:
    """Stop the app (once) and return the last lines of its log."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    log_file.close()
    return path.read_text(errors="replace").splitlines()[-lines:]


def format_report(r: dict) -> str:
    s, u = r.get("single", {}), r.get("under_load", {})
    lines = [
        f"machine: {r['cpus']} CPUs, load average before {r['loadavg_before']}, during "
        f"{r.get('loadavg_during')}",
        f"ready: HTTP {r.get('ready_http_s')} s, first /query {r.get('ready_query_s')} s "
        "after launch",
        f"single user: p50 {s.get('p50_s')} s, p95 {s.get('p95_s')} s ({s.get('n')} queries; "
        f"the pipeline itself {s.get('pipeline_mean_s')} s on average)",
        f"{r['clients']} clients x {r['queries_per_client']} queries "
        f"({r.get('sessions', 'one per client')}): p50 {u.get('p50_s')} s, "
        f"p95 {u.get('p95_s')} s, max {u.get('max_s')} s, {u.get('n')} answered, "
        f"{r.get('failures')} failed, {r.get('not_run')} not run, "
        f"{r.get('throughput_qps')} queries/s over {r.get('load_wall_s')} s (model "
        f"{r.get('model')!r})",
        f"  the pipeline itself {u.get('pipeline_mean_s')} s per batch on average, batches of "
        f"{u.get('mean_batch')} queries on average (per answered query)",
        f"  CPU seconds per query under load: {r.get('cpu_s_per_query')} (the app, the "
        f"load-generating clients and everything else on the machine); the machine's "
        f"{r['cpus']} CPUs were {r.get('machine_busy', 0):.0%} busy",
        f"p50 under load / single-user p50: {r.get('ratio_p50')}",
        f"server RSS: {r.get('rss_before_mib')} MiB before the load, {r.get('rss_after_mib')} "
        "MiB after",
        "targets: " + ", ".join(f"{k}: {'met' if ok else 'NOT met'}"
                                for k, ok in r["targets"].items()),
    ]
    for kind, n in (r.get("failure_kinds") or {}).items():
        lines.append(f"FAILED x{n}: {kind}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clients", type=int, default=16)
    p.add_argument("--queries", type=int, default=10, help="queries per client")
    p.add_argument("--single", type=int, default=8, help="sequential single-user queries")
    p.add_argument("--deadline", type=float, default=120.0,
                   help="longest load phase (s): queries not sent by then count as not run")
    p.add_argument("--timeout", type=float, default=900.0,
                   help="longest whole run (s), launch to report (default 900)")
    p.add_argument("--max-batch", type=int, default=None,
                   help="passed to the app (1 answers every query on its own)")
    p.add_argument("--batch-workers", type=int, default=None,
                   help="passed to the app: batches answered at once (default: the app's)")
    p.add_argument("--model-processes", type=int, default=None,
                   help="passed to the app: model processes (default: the app's)")
    p.add_argument("--corpus", default=None,
                   help="passed to the app: a built corpus folder (default: the world's 10k)")
    p.add_argument("--model", default=None,
                   help="the model every query names (default: the app's default)")
    p.add_argument("--sessions", choices=("client", "query"), default="client",
                   help="one Gradio session per client (default, as a browser tab or "
                        "gradio_client keeps one) or a new one per query")
    p.add_argument("--warm-load", type=int, default=0,
                   help="queries per client sent before the measured load, not counted")
    p.add_argument("--json", default=None, help="also write the report here")
    p.add_argument("--check", action="store_true", help="exit 1 when a target is not met")
    args = p.parse_args(argv)
    passed = {"--max-batch": args.max_batch, "--batch-workers": args.batch_workers,
              "--model-processes": args.model_processes, "--corpus": args.corpus}
    app_args = tuple(x for flag, value in passed.items() if value is not None
                     for x in (flag, str(value)))
    try:
        r = run(args.clients, args.queries, args.single, deadline_s=args.deadline,
                app_args=app_args, log=lambda m: print(m, flush=True), model=args.model,
                timeout_s=args.timeout, sessions=args.sessions, warm_load=args.warm_load)
    except LoadTestError as e:
        print(f"load test FAILED: {e}", file=sys.stderr)
        tail = getattr(e, "server_log", None)
        if tail:
            print("the app's log ends:\n  " + "\n  ".join(tail), file=sys.stderr)
        return 1
    print(format_report(r))
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1) + "\n")
    if r["failures"]:
        print(f"load test FAILED: {r['failures']} of {r['failures'] + r['answered']} queries "
              f"under load failed (by kind: {r['failure_kinds']})", file=sys.stderr)
        return 1
    return 1 if args.check and not all(r["targets"].values()) else 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    sys.exit(main())
