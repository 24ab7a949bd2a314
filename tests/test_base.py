"""The base helpers every layer shares: atomic writes (`ratouch.files`), the stopwatch and the
progress convention (`ratouch.timing`), and the registries of encoder sets, index kinds and
system names the command line offers."""

from __future__ import annotations

import json
import logging
import os

import numpy as np
import pytest


def test_atomic_writes_leave_the_old_file_on_failure(tmp_path):
    from ratouch.files import atomic_path, write_atomic, write_json_atomic, write_npz_atomic

    path = tmp_path / "sub" / "a.json"
    write_json_atomic(path, {"b": 1, "a": [1, 2]})
    assert path.read_text() == json.dumps({"b": 1, "a": [1, 2]}, indent=1) + "\n"
    write_json_atomic(path, {"b": 1, "a": 2}, indent=2, sort_keys=True, newline=False)
    assert path.read_text() == json.dumps({"a": 2, "b": 1}, indent=2)
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert json.loads(path.read_text()) == {"a": 2, "b": 1}
    assert sorted(p.name for p in path.parent.iterdir()) == ["a.json"]  # no leftovers
    write_atomic(tmp_path / "t.txt", "text")
    assert (tmp_path / "t.txt").read_text() == "text"
    write_npz_atomic(tmp_path / "x.npz", a=np.arange(3))
    with np.load(tmp_path / "x.npz") as z:
        assert z["a"].tolist() == [0, 1, 2]


def test_staged_files_are_published_in_order_or_not_at_all(tmp_path):
    from ratouch.files import publish, replace_folder, staged

    out = tmp_path / "out"
    with staged(out) as tmp:
        (tmp / "data").write_text("d")
        (tmp / "deep").mkdir()
        (tmp / "deep" / "x").write_text("x")
        publish(tmp, out)
    assert (out / "data").read_text() == "d" and (out / "deep" / "x").read_text() == "x"
    with pytest.raises(RuntimeError), staged(out) as tmp:
        (tmp / "manifest").write_text("m")
        raise RuntimeError("interrupted")
    assert sorted(p.name for p in out.iterdir()) == ["data", "deep"]
    new = tmp_path / "new"
    new.mkdir()
    (new / "only").write_text("o")
    replace_folder(new, out)
    assert [p.name for p in out.iterdir()] == ["only"] and not new.exists()


def test_laps_and_the_progress_convention(caplog):
    from ratouch.timing import Laps, bars, say_to

    clock = Laps()
    clock.lap("a")
    clock.lap("b")
    clock.lap("a")
    assert list(clock.laps) == ["a", "b"] and all(v >= 0 for v in clock.laps.values())
    assert clock.elapsed() >= sum(clock.laps.values())
    assert set(clock.ms()) == set(clock.seconds()) == {"a", "b"}
    got: list[str] = []
    say_to(got.append)("point %d of %d", 1, 2)
    say_to(got.append)("plain 100%")
    assert got == ["point 1 of 2", "plain 100%"]
    log = logging.getLogger("ratouch.test")
    with caplog.at_level(logging.DEBUG, logger="ratouch.test"):
        say_to(True, log)("shown")
        say_to(None, log)("quiet")
    assert [(r.levelno, r.getMessage()) for r in caplog.records] == [
        (logging.INFO, "shown"), (logging.DEBUG, "quiet")]
    assert bars(True) and not bars(False) and not bars(None) and not bars(print)


def test_registries_are_the_command_lines_choices():
    from ratouch.cli.parser import build_parser
    from ratouch.encoders.factory import CHAIN_SETS, DEFAULT_SETS, MODEL_CONFIGS
    from ratouch.eval.catalog import SYSTEMS
    from ratouch.search.index import KINDS, ONDISK_KINDS

    assert all(MODEL_CONFIGS[n]["backend"] == "default" for n in DEFAULT_SETS)
    assert set(CHAIN_SETS) <= set(DEFAULT_SETS) and set(ONDISK_KINDS) <= set(KINDS)
    parser = build_parser()
    args = parser.parse_args(["eval", "tvl", "--system", SYSTEMS[1], "--out", "x.json"])
    assert args.system == "ra-touch" and args.encoder == "default-s"
    for kind in KINDS:
        assert parser.parse_args(["query", "--vision", "v.png", "--index", kind]).index == kind
    with pytest.raises(SystemExit):
        parser.parse_args(["eval", "tvl", "--system", "ra_touch", "--out", "x.json"])
    assert parser.parse_args(["train", "cascade"]).encoders == ",".join(CHAIN_SETS)


def test_a_killed_writers_temporary_file_is_removed_by_the_next_write(tmp_path):
    from ratouch.files import write_atomic

    path = tmp_path / "report.md"
    write_atomic(path, "old")
    dead = tmp_path / f".report.md.partial-{2**22 + 12345}-abcd"  # no process has that pid
    older = tmp_path / ".report.md.partial"  # an older version's name, without a pid
    alive = tmp_path / f".report.md.partial-{os.getpid()}-beef"  # a writer running now
    for p in (dead, older, alive):
        p.write_text("half")
    write_atomic(path, "new")
    assert path.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["report.md", alive.name])


def test_replace_folder_swaps_a_whole_folder_in(tmp_path):
    from ratouch.files import replace_folder, staged_beside

    out = tmp_path / "ck"
    out.mkdir()
    (out / "a").write_text("old")
    (out / "b").write_text("old")
    with staged_beside(out) as tmp:
        (tmp / "a").write_text("new")
        replace_folder(tmp, out)
    assert sorted(p.name for p in out.iterdir()) == ["a"] and (out / "a").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ck"]  # the old version is gone


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads the Linux process table")
def test_a_killed_owners_tagged_processes_are_ended_by_its_reaper(tmp_path):
    """What a process starts through another program (a local Ray's agents) carries its tag;
    when the owner is killed (SIGKILL: no clean-up of its own), its reaper ends them all."""
    import signal
    import subprocess
    import sys
    import time

    from ratouch.paths import REPO
    from ratouch.processes import _running, end_orphans, tagged

    owner_code = (
        "import os, subprocess, sys, time\n"
        "from ratouch.processes import TAG_VAR, start_reaper\n"
        "tag = f'{os.getpid()}-test'\n"
        "start_reaper(tag, sys.argv[1])\n"
        "env = {**os.environ, TAG_VAR: tag}\n"
        "kids = [subprocess.Popen(['sleep', '300'], env=env, start_new_session=True)\n"
        "        for _ in range(2)]\n"
        "print(' '.join(str(k.pid) for k in kids), flush=True)\n"
        "time.sleep(300)\n")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    owner = subprocess.Popen([sys.executable, "-c", owner_code, str(REPO)], env=env,
                             stdout=subprocess.PIPE, text=True)
    kids = [int(k) for k in owner.stdout.readline().split()]
    try:
        # the kids are read from the process table: give a loaded machine a moment to show them
        want = f"{owner.pid}-test"
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not all(tagged().get(k) == want for k in kids):
            time.sleep(0.1)
        found = tagged()
        assert len(kids) == 2 and all(found.get(k) == want for k in kids), \
            (kids, want, {k: found.get(k) for k in kids}, [_running(k) for k in kids])
        owner.send_signal(signal.SIGKILL)
        owner.wait()
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and any(_running(k) for k in kids):
            time.sleep(0.1)
        assert not [k for k in kids if _running(k)], "the owner's processes outlived it"
        assert end_orphans() == []  # nothing of a dead owner is left
    finally:
        for k in kids:
            if _running(k):
                os.kill(k, signal.SIGKILL)
