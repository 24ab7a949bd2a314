"""Faults survived: long jobs killed (SIGKILL) at the wrong moment, numbers a user types that
are infinite or beyond 64 bits, huge uploads of every image mode. Real processes, real files,
the real process table."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ratouch.cli import main
from ratouch.errors import DataError, DataNotFoundError
from ratouch.images import QUERY_MAX_SIDE, to_rgb_array
from ratouch.serve.request import QueryRequest
from ratouch.world.dataset import read_tvl

REPO = Path(__file__).resolve().parents[1]
BUILD = ["world", "build", "--split", "train", "--n", "48", "--workers", "2"]


def _ratouch(args: list[str], code: str = "") -> subprocess.Popen:
    """`ratouch ARGS` in a child process, after running `code` in it (a fault to inject)."""
    script = f"import sys\n{code}\nfrom ratouch.cli import main\nsys.exit(main({args!r}))"
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    return subprocess.Popen([sys.executable, "-c", script], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _children(pid: int) -> set[int]:
    kids: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            kids.update(int(k) for k in (task / "children").read_text().split())
        except OSError:
            pass
    return kids


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _staging(out: Path) -> list[Path]:
    return [p for p in out.rglob(".partial*")] if out.exists() else []


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads the Linux process table")
def test_world_build_killed_during_work_leaves_nothing_and_no_orphans(tmp_path):
    out = tmp_path / "tvl"
    proc = _ratouch([*BUILD, "--out", str(out)])
    deadline = time.time() + 120
    workers: set[int] = set()
    while time.time() < deadline:  # kill it once its workers have rendered some pairs
        workers |= _children(proc.pid)
        if any(out.glob(".partial-train-*/*/vision/*.png")) and workers:
            break
        time.sleep(0.05)
    assert workers, "the build never started its workers"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    # the reader sees nothing: no CSV outside the staging folder
    with pytest.raises(DataNotFoundError):
        read_tvl(out, "train")
    # no orphans: the workers end with their parent
    deadline = time.time() + 10
    while any(_alive(w) for w in workers) and time.time() < deadline:
        time.sleep(0.1)
    assert not [w for w in workers if _alive(w)], "render workers outlived their parent"
    assert _staging(out)
    rerun = _ratouch([*BUILD, "--out", str(out)])
    _, err = rerun.communicate(timeout=300)
    assert rerun.returncode == 0, err
    assert "removed the staging folder" in err
    assert not _staging(out)
    records = read_tvl(out, "train")
    assert len(records) == 48 and all(r.vision.is_file() for r in records)


@pytest.mark.slow
def test_world_build_killed_while_publishing_is_refused_then_finished(tmp_path):
    out = tmp_path / "tvl"
    # the worst order: a CSV lands, then the process dies before the images it names
    fault = ("import os, signal\nimport ratouch.world.dataset as ds\nreal = ds.publish\n"
             "def dying(staging, folder, names):\n"
             "    names = list(names)\n"
             "    real(staging, folder, [n for n in names if n.endswith('.csv')][:1] + names[:5])\n"
             "    os.kill(os.getpid(), signal.SIGKILL)\n"
             "ds.publish = dying\n")
    proc = _ratouch([*BUILD[:-1], "1", "--out", str(out)], fault)
    proc.communicate(timeout=300)
    assert proc.returncode == -signal.SIGKILL
    assert list(out.rglob("train.csv"))  # a CSV is in place, naming images that are not
    with pytest.raises(DataError, match="killed while publishing.*ratouch world build"):
        read_tvl(out, "train")
    rerun = _ratouch([*BUILD, "--out", str(out)])
    _, err = rerun.communicate(timeout=300)
    assert rerun.returncode == 0, err
    assert "publishes it again" in err and "removed the staging folder" in err
    assert not _staging(out) and not list(out.glob(".publishing-*"))
    records = read_tvl(out, "train")
    assert len(records) == 48 and len({r.vision for r in records}) == 48
    assert all(r.vision.is_file() and r.tactile.is_file() for r in records)


def test_reader_never_lists_staging_folders_at_any_depth(tmp_path):
    sub = tmp_path / ".partial-test-1-x" / "hct" / "data1"
    sub.mkdir(parents=True)
    (sub / "test.csv").write_text("url,tactile,background,caption\nv.png,t.png,b.png,soft\n")
    with pytest.raises(DataNotFoundError):
        read_tvl(tmp_path, "test")


def test_corpus_build_rerun_keeps_overwrite_replaces(tmp_path, capsys):
    out = tmp_path / "corpus"
    args = ["corpus", "build", "--size", "12", "--out", str(out), "--no-embed"]
    assert main(args) == 0
    first = json.loads(capsys.readouterr().out)
    assert first["resumed"] is False
    assert main(args) == 0  # the same command again: the corpus is kept, and it says so
    captured = capsys.readouterr()
    assert json.loads(captured.out)["resumed"] is True
    assert "already holds this corpus" in captured.err
    assert main([*args[:3], "16", *args[4:]]) == 2  # another size: refused, with the way out
    err = capsys.readouterr().err
    assert "size 12 (asked 16)" in err and "--overwrite" in err and err.count("\n") == 1
    assert main([*args[:3], "16", *args[4:], "--overwrite"]) == 0
    assert json.loads(capsys.readouterr().out)["size"] == 16


@pytest.mark.parametrize("argv, named", [
    (["--box", "0,0,inf,10"], "'inf' is not a finite number"),
    (["--box", "0,0,nan,10"], "'nan' is not a finite number"),
    (["--box", "0,0,1e308,1e308"], "'1e308' is beyond the 64-bit range"),
    (["--box", "0,0,1e20,10"], "'1e20' is beyond the 64-bit range"),
    (["--k", "99999999999999999999"], "'99999999999999999999' is beyond the 64-bit range"),
    (["--k", "inf"], "'inf' is not an integer"),
])
def test_numbers_typed_get_one_line_naming_the_value(tmp_path, capsys, argv, named):
    img = tmp_path / "v.png"
    Image.new("RGB", (64, 64)).save(img)
    with pytest.raises(SystemExit) as e:
        main(["query", "--vision", str(img), *argv])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert named in err and err.count("\n") == 1


def test_query_k_has_the_apps_bound(tmp_path, capsys):
    img = tmp_path / "v.png"
    Image.new("RGB", (64, 64)).save(img)
    assert main(["query", "--vision", str(img), "--k", "21"]) == 2  # before any model loads
    assert "K must be a whole number from 1 to 20, got K=21" in capsys.readouterr().err


def test_a_directory_as_vision_is_called_a_directory(tmp_path, capsys):
    assert main(["query", "--vision", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_the_box_reported_is_the_box_used(tmp_path):
    img = tmp_path / "v.png"
    Image.new("RGB", (100, 80)).save(img)
    req = QueryRequest.decode(str(img), None, box=(-5, 10.5, 1e15, 70))
    assert req.box == (0, 10, 100, 70)
    for box, named in (((0, 0, 1e20, 10), "x1=1e+20 is beyond the 64-bit range"),
                       ((0, 0, float("inf"), 10), "x1=inf is not finite"),
                       ((float("nan"), 0, 5, 10), "x0=nan is not finite")):
        with pytest.raises(DataError, match=re.escape(named)):
            QueryRequest.decode(str(img), None, box=box)


@pytest.mark.parametrize("mode", ["I;16", "1", "P", "CMYK", "F", "I", "LA", "PA"])
def test_every_mode_is_reduced_and_matches_a_full_conversion(tmp_path, mode):
    """The band-wise reduction gives what converting the whole image first gave."""
    rng = np.random.default_rng(0)
    base = Image.fromarray(rng.integers(0, 255, (900, 1300, 3), dtype=np.uint8))
    if mode == "I;16":
        img = Image.fromarray((np.asarray(base.convert("L"), np.uint16) * 257))
    elif mode == "F":
        img = Image.fromarray(np.asarray(base.convert("L"), np.float32) / 255)
    elif mode == "I":
        img = base.convert("L").convert("I")
    elif mode == "PA":
        img = base.convert("P").convert("PA")
    else:
        img = base.convert(mode)
    small = to_rgb_array(img, max_side=QUERY_MAX_SIDE)
    full = to_rgb_array(img)
    ref = np.asarray(Image.fromarray(full).resize(small.shape[1::-1], Image.Resampling.BILINEAR))
    assert max(small.shape[:2]) == QUERY_MAX_SIDE
    assert np.abs(small.astype(int) - ref.astype(int)).mean() < 12


def test_bench_memory_prints_each_mode_and_the_burst(capsys):
    assert main(["bench", "memory", "--side", "400", "--burst", "3", "--modes", "I;16,1,L",
                 "--box-side", "64", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert [row["mode"] for row in r["rows"]] == ["I;16", "1", "L"]
    assert all(not row["errors"] for row in r["rows"]) and r["burst"]["n"] == 3
    assert not r["burst"]["errors"]


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="needs /dev/zero")
def test_a_device_as_an_input_is_called_what_it_is(tmp_path, capsys):
    img = tmp_path / "v.png"
    Image.new("RGB", (64, 64)).save(img)
    assert main(["query", "--vision", "/dev/zero"]) == 2
    assert "visual image /dev/zero is a character device, not an image file" in \
        capsys.readouterr().err
    assert main(["query", "--vision", str(img), "--tactile", "/dev/zero"]) == 2
    assert "tactile image /dev/zero is a character device" in capsys.readouterr().err
    with pytest.raises(DataError, match="/dev/zero is a character device, not an image"):
        QueryRequest.decode("/dev/zero", None)  # the app's and the API's way in too


def test_k_is_capped_at_the_apps_twenty_everywhere(tmp_path, capsys):
    from ratouch.errors import ConfigError
    from ratouch.serve.request import MAX_K

    img = tmp_path / "v.png"
    Image.new("RGB", (64, 64)).save(img)
    assert MAX_K == 20 and QueryRequest.decode(str(img), None, k=20).k == 20
    for k in (21, 10_000):
        with pytest.raises(ConfigError, match=f"from 1 to 20, got K={k}"):
            QueryRequest.decode(str(img), None, k=k)
    assert main(["query", "--vision", str(img), "--k", "10000"]) == 2
    err = capsys.readouterr().err
    assert "K must be a whole number from 1 to 20" in err and err.count("\n") == 1


@pytest.mark.slow
def test_a_training_run_killed_while_saving_leaves_a_checkpoint_that_loads(tmp_path):
    """`ratouch train generator` saves baseline/ and ra/ (weights, adapter, tokenizer,
    manifest): a process SIGKILLed at random moments while saving one generator after another
    leaves, each time, a checkpoint that loads (the old or the new one, never a mixture), and
    the next save removes what the kill left."""
    from ratouch.model.generator import load_generator, save_generator

    folder = tmp_path / "generator" / "debug" / "baseline"
    saver = ("import sys, torch\n"
             "from ratouch.model.decoder import DecoderConfig, build_small_decoder\n"
             "from ratouch.model.generator import (BaselinePrompt, PromptConfig,\n"
             "                                     RATouchGenerator, save_generator)\n"
             "from ratouch.vocabulary import TVL_ADJECTIVES\n"
             "cfg = DecoderConfig(hidden=32, layers=1, heads=2, intermediate=32, lora_r=2)\n"
             "for seed in range(10**6):\n"
             "    torch.manual_seed(seed)\n"
             "    dec = build_small_decoder(cfg, TVL_ADJECTIVES[:24], seed=seed)\n"
             "    dec.add_lora()\n"
             "    gen = RATouchGenerator(BaselinePrompt(PromptConfig(dim=16, out_dim=32)), dec)\n"
             "    save_generator(sys.argv[1], gen)\n"
             "    print(seed, flush=True)\n")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    rng = np.random.default_rng(0)
    for _ in range(3):
        proc = subprocess.Popen([sys.executable, "-c", saver, str(folder)], env=env,
                                stdout=subprocess.PIPE, text=True)
        proc.stdout.readline()  # one checkpoint saved: the next saves overwrite it
        time.sleep(float(rng.uniform(0.0, 0.3)))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        load_generator(folder)  # whichever version it is, it is whole
    leftovers = [p for p in folder.parent.iterdir() if p.name.startswith(".")]
    save_generator(folder, load_generator(folder))
    assert not [p for p in folder.parent.iterdir() if p.name.startswith(".")], leftovers
