"""The ratouch CLI, called as a user would (main(argv))."""

from __future__ import annotations

import argparse
import json

import pytest
import torch
from PIL import Image

from ratouch.cli import main


def test_world_preview_writes_a_contact_sheet(tmp_path, capsys):
    out = tmp_path / "sheet.png"
    assert main(["world", "preview", "--out", str(out), "--n", "6", "--columns", "3"]) == 0
    im = Image.open(out)
    assert im.size[0] > 600 and im.size[1] > 300
    assert "6 samples" in capsys.readouterr().out


def test_world_build_small_train_split(tmp_path, capsys):
    assert main(["world", "build", "--out", str(tmp_path / "d"), "--n", "12", "--workers", "1",
                 "--seed", "2"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["structured"] + summary["wild"] == 12


@pytest.mark.parametrize("argv", [
    ["world", "build", "--out", "{tmp}/x", "--n", "-3"],
    ["world", "build", "--out", "{tmp}/x", "--n", "0"],
    ["world", "build", "--out", "{tmp}/x", "--split", "val"],
    ["world", "build", "--out", "{tmp}/x", "--split", "test", "--n", "10"],
    ["world", "build", "--out", "{tmp}/x", "--object-scale", "5"],
    ["world", "preview", "--out", "{tmp}/x.jpg"],
    ["corpus", "build", "--size", "-5", "--out", "{tmp}/x"],
    ["corpus", "build", "--size", "10k", "--out", "{tmp}/x", "--captioner", "llm"],
    ["train", "encoders", "--model", "debug", "--out", "{tmp}/x", "--device", "gpu0"],
    pytest.param(["train", "encoders", "--model", "debug", "--out", "{tmp}/x", "--device", "cuda"],
                 marks=pytest.mark.skipif(torch.cuda.is_available(), reason="a GPU is seen")),
])
def test_bad_arguments_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, argv):
    argv = [a.format(tmp=tmp_path) for a in argv]
    with pytest.raises(SystemExit) as e:
        code = main(argv)
        raise SystemExit(code)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "error" in err
    assert list(tmp_path.iterdir()) == []


def test_unwritable_output_folder(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        import os

        if os.access(ro, os.W_OK):
            pytest.skip("running as a user that can write anywhere")
        assert main(["world", "build", "--out", str(ro / "x"), "--n", "5"]) == 2
        assert "not writable" in capsys.readouterr().err
    finally:
        ro.chmod(0o700)


def test_file_in_the_way_of_the_output_folder(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["world", "build", "--out", str(f / "sub"), "--n", "5"]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert f.read_text() == "x"


def test_corpus_build_prints_manifest(tmp_path, capsys):
    assert main(["corpus", "build", "--size", "300", "--out", str(tmp_path / "c")]) == 0
    manifest = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert manifest["size"] == 300 and manifest["captioner"] == "offline"


def _commands(parser, path=()):
    """(path, parser, module) of every command, the groups included; `module` is the
    ratouch.cli module the parser names for it (set on the command or on its group)."""
    import argparse

    module = parser.get_default("module")
    yield path, parser, module
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                for p, child, m in _commands(sub, (*path, name)):
                    yield p, child, m or module


def test_every_command_has_help(capsys):
    from ratouch.cli import build_parser

    paths = [p for p, _, _ in _commands(build_parser())]
    assert len(paths) > 30 and ("eval", "stress") in paths and ("judge",) in paths
    for path in paths:
        with pytest.raises(SystemExit) as e:
            main([*path, "--help"])
        assert e.value.code == 0, path
        out = capsys.readouterr().out
        assert out.startswith(f"usage: {' '.join(('ratouch', *path))}"), (path, out[:80])
    assert "a thin client of the library" in (build_parser().format_help())


def test_every_command_names_a_module_that_runs_it():
    import ast
    import importlib.util
    from pathlib import Path

    from ratouch.cli import build_parser

    for path, parser, module in _commands(build_parser()):
        if any(isinstance(a, argparse._SubParsersAction) for a in parser._actions):
            continue  # a group: its subcommands are run
        assert module, path
        spec = importlib.util.find_spec(f"ratouch.cli.{module}")
        assert spec is not None, (path, module)
        tree = ast.parse(Path(spec.origin).read_text())
        assert any(isinstance(n, ast.FunctionDef) and n.name == "run" for n in tree.body), module


def test_building_the_parser_imports_no_model_side():
    """`ratouch --help` and usage errors stay fast: the command modules, which import torch,
    faiss and transformers at their top, are imported only when their command runs."""
    import subprocess
    import sys

    code = ("import sys\nfrom ratouch.cli import build_parser, main\nbuild_parser()\n"
            "try:\n    main(['eval', 'stress', '--help'])\nexcept SystemExit:\n    pass\n"
            "heavy = {'torch', 'faiss', 'transformers', 'ray'} & set(sys.modules)\n"
            "cli = sorted(m for m in sys.modules if m.startswith('ratouch.cli.'))\n"
            "print(sorted(heavy), cli)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip().splitlines()[-1]
    assert out == "[] ['ratouch.cli.parser']"


@pytest.mark.slow
def test_bench_query_times_every_system_with_and_without_a_background(shipped_corpus, capsys):
    """`ratouch bench query` as the closing notes run it (on the 600-entry test corpus): warm
    latency without and with each pair's background, and every retrieval system's."""
    from ratouch.search.modes import RETRIEVAL_SYSTEMS

    assert main(["bench", "query", "--corpus", str(shipped_corpus), "--n", "3", "--json"]) == 0
    r = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert r["encoder"] == "default-s" and r["corpus_size"] == 600 and r["n_queries"] == 3
    assert 0 < r["p50_ms"] <= r["p95_ms"]
    assert 0 < r["with_background"]["p50_ms"] <= r["with_background"]["p95_ms"]
    assert set(r["by_retrieval"]) == set(RETRIEVAL_SYSTEMS)
    assert all(v["p50_ms"] > 0 for v in r["by_retrieval"].values())
