"""Checkpoints: every file a checkpoint needs is in its manifest and checked on load, a damaged
file or manifest is one clear error naming the file and the command that rebuilds it, and a
checkpoint is published as a whole (a save that dies at any step leaves the old one or the
new one, never a mixture, and the next save removes what it left)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
import torch

import ratouch.files as files
from ratouch.checkpoint import MANIFEST, _hashes, read_checkpoint, rehash_manifest
from ratouch.errors import DataError, DataNotFoundError
from ratouch.model.decoder import DecoderConfig, build_small_decoder
from ratouch.model.generator import (
    BaselinePrompt,
    PromptConfig,
    RATouchGenerator,
    load_generator,
    save_generator,
)
from ratouch.paths import ASSETS
from ratouch.vocabulary import TVL_ADJECTIVES

pytestmark = pytest.mark.usefixtures("one_thread")

D, DP = 16, 32
REBUILD = "ratouch train generator --encoder debug"


def make_gen(seed: int) -> RATouchGenerator:
    torch.manual_seed(seed)
    cfg = DecoderConfig(hidden=DP, layers=1, heads=2, intermediate=32, max_new_tokens=4,
                        lora_r=2, lora_alpha=4)
    dec = build_small_decoder(cfg, TVL_ADJECTIVES[:24], seed=seed)
    dec.add_lora()
    with torch.no_grad():  # LoRA B starts at zero: give it values a lost adapter would show
        for name, p in dec.named_parameters():
            if "lora_B" in name:
                p.normal_(0, 0.5)
    return RATouchGenerator(BaselinePrompt(PromptConfig(dim=D, out_dim=DP)), dec).eval()


def fingerprint(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


@pytest.fixture
def saved(tmp_path) -> Path:
    """A generator with a LoRA adapter, in the shipped layout (generator/<set>/<kind>)."""
    folder = tmp_path / "generator" / "debug" / "baseline"
    save_generator(folder, make_gen(0))
    return folder


def test_the_manifest_records_every_file_the_checkpoint_holds(saved):
    manifest = json.loads((saved / MANIFEST).read_text())
    on_disk = {p.relative_to(saved).as_posix() for p in saved.rglob("*") if p.is_file()}
    assert set(manifest["files"]) == on_disk - {MANIFEST}
    assert {"tokenizer.json", "adapter/adapter_model.safetensors",
            "adapter/adapter_config.json"} <= set(manifest["files"])
    assert not list(saved.parent.glob(".*"))  # no staging left beside it


@pytest.mark.parametrize("name", ["adapter/adapter_model.safetensors", "tokenizer.json",
                                  "adapter/adapter_config.json", "model.safetensors"])
@pytest.mark.parametrize("damage", ["scramble", "truncate"])
def test_a_damaged_file_is_refused_naming_it_and_the_rebuild(saved, name, damage):
    path = saved / name
    data = bytearray(path.read_bytes())
    if damage == "scramble":  # 4,000 bytes (or all of a small file) scrambled
        n = min(4000, len(data))
        data[-n:] = os.urandom(n)
    else:
        data = data[: len(data) // 2]
    path.write_bytes(bytes(data))
    with pytest.raises(DataError, match=rf"{name} is corrupt .*`{REBUILD}`"):
        load_generator(saved)


@pytest.mark.parametrize("content", [b"\xff\xfe{\"files\": {}}", b"", b"{\"files\": {\"x",
                                     b"[]", b"{\"files\": [1]}",
                                     b"{\"files\": {\"../etc/passwd\": \"0\"}}"])
def test_an_unreadable_manifest_is_one_clear_error(saved, content):
    (saved / MANIFEST).write_bytes(content)
    with pytest.raises(DataError, match=rf"{MANIFEST} is unreadable .*`{REBUILD}`"):
        load_generator(saved)


def test_a_missing_file_names_it(saved):
    (saved / "tokenizer.json").unlink()
    with pytest.raises(DataNotFoundError, match=rf"tokenizer.json is missing; .*`{REBUILD}`"):
        load_generator(saved)


def test_an_older_manifest_is_refused_until_rehashed(saved):
    """A checkpoint written before adapters and tokenizers were recorded cannot be checked;
    `rehash_manifest` records them (the way the shipped assets' manifests were updated)."""
    manifest = json.loads((saved / MANIFEST).read_text())
    manifest["files"] = {k: v for k, v in manifest["files"].items()
                         if k in ("model.safetensors", "config.json")}
    (saved / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(DataError, match="tokenizer.json is not recorded in manifest.json"):
        load_generator(saved)
    added = rehash_manifest(saved)
    assert "adapter/adapter_model.safetensors" in added and "tokenizer.json" in added
    load_generator(saved)
    # a weights file that no longer matches its recorded checksum is never blessed
    (saved / "model.safetensors").write_bytes(b"junk")
    with pytest.raises(DataError, match="corrupt"):
        rehash_manifest(saved)


@pytest.mark.parametrize("folder", sorted(p.parent.relative_to(ASSETS).as_posix()
                                          for p in ASSETS.rglob(MANIFEST)))
def test_shipped_manifests_record_every_file(folder):
    manifest = json.loads((ASSETS / folder / MANIFEST).read_text())
    assert list(manifest["files"]) == list(_hashes(ASSETS / folder))  # same files, same order
    read_checkpoint(ASSETS / folder)  # and every checksum holds


DEAD_PID = 2**22 + 12345  # above Linux's largest pid: no process has it


def _dies_at(monkeypatch, step: int) -> list[str]:
    """Make the `step`-th file-system move (rename, replace, exchange, removal) of a save its
    last, as if the process were killed there: that move and every later one do nothing, and
    the staging it names belongs to a process that no longer runs. Returns the moves made."""
    calls: list[str] = []

    def wrap(name, real):
        def move(*args, **kwargs):
            calls.append(name)
            if step and len(calls) >= step:
                return False if name == "exchange" else None
            return real(*args, **kwargs)
        return move

    monkeypatch.setattr(os, "replace", wrap("replace", os.replace))
    monkeypatch.setattr(os, "rename", wrap("rename", os.rename))
    monkeypatch.setattr(files, "_exchange", wrap("exchange", files._exchange))
    monkeypatch.setattr(shutil, "rmtree", wrap("rmtree", shutil.rmtree))
    if step:
        monkeypatch.setattr(os, "getpid", lambda: DEAD_PID)
    return calls


@pytest.mark.parametrize("exchange", [True, False], ids=["exchange", "two-renames"])
def test_a_save_killed_at_any_move_leaves_old_or_new(tmp_path, monkeypatch, exchange):
    assert not files.pid_alive(DEAD_PID)
    folder = tmp_path / "generator" / "debug" / "ra"
    old, new = make_gen(0), make_gen(1)
    save_generator(tmp_path / "old", old)
    save_generator(tmp_path / "new", new)
    before, after = fingerprint(tmp_path / "old"), fingerprint(tmp_path / "new")
    if not exchange:  # where the system cannot exchange two folders: two renames
        monkeypatch.setattr(files, "_exchange", lambda a, b: False)
    with monkeypatch.context() as m:  # the moves of a save over an existing checkpoint
        calls = _dies_at(m, 0)
        save_generator(tmp_path / "new", new)
    assert calls and calls[0] in ("exchange", "replace")
    outcomes = set()
    for step in range(1, len(calls) + 1):
        save_generator(folder, old)
        with monkeypatch.context() as m:
            _dies_at(m, step)
            save_generator(folder, new)
        if folder.exists():
            seen = fingerprint(folder)
            assert seen in (before, after), f"a mixture after a kill at move {step}"
            load_generator(folder)  # what a reader sees loads
            outcomes.add("new" if seen == after else "old")
        else:  # only between the fallback's two renames; the next save puts it back
            assert not exchange and list(folder.parent.glob(".ra.old-*"))
            outcomes.add("none")
        save_generator(folder, new)  # the rerun finishes and removes what the kill left
        assert fingerprint(folder) == after
        assert not [p.name for p in folder.parent.iterdir() if p.name.startswith(".")], step
    assert "old" in outcomes and "new" in outcomes
