"""The TVL data set layout: the world's output and a hand-built copy of the real layout."""

from __future__ import annotations

import csv
import os

import numpy as np
import pytest
from PIL import Image

from ratouch.errors import ConfigError, DataError, DataNotFoundError
from ratouch.world.config import WorldConfig
from ratouch.world.dataset import CSV_HEADER, read_tvl, write_split


def test_test_split_has_tvl_sizes_and_layout(test_split_dir):
    root, counts = test_split_dir
    assert counts == {"structured": 46, "wild": 356}
    for sub, n in (("ssvtp", 46), ("hct/data1", 356)):
        with open(root / sub / "test.csv", newline="") as f:
            rows = list(csv.reader(f))
        assert tuple(rows[0]) == CSV_HEADER
        assert len(rows) == n + 1
        assert all(len(r) == 4 for r in rows)
        vision, tactile, background, caption = rows[1]
        for rel in (vision, tactile, background):
            assert (root / sub / rel).is_file()
        assert 2 <= len(caption.split(", ")) <= 5
    assert not [p for p in root.iterdir() if p.name.startswith(".partial")]


def test_round_trip_matches_the_generator(test_split_dir, world):
    root, _ = test_split_dir
    records = read_tvl(root, "test")
    assert len(records) == 402
    for rec in records[::50]:
        s = world.sample("test", rec.meta["index"])
        assert rec.caption == s.caption
        assert rec.meta["material"] == s.material and rec.meta["box"] == list(s.box)
        assert np.array_equal(np.asarray(Image.open(rec.vision)), s.visual)
        assert np.array_equal(np.asarray(Image.open(rec.tactile)), s.tactile)
        bg = np.asarray(Image.open(rec.background))
        assert np.array_equal(bg, world.background_image(s.sensor))


def test_reader_loads_the_real_tvl_layout(tmp_path):
    """A small folder in the exact layout of the TVL data set (Max-Fu/tvl, tacvis.py):
    tvl_dataset/ssvtp and tvl_dataset/hct/dataN, each with a header row and relative paths."""
    root = tmp_path / "tvl_dataset"
    img = Image.new("RGB", (8, 8), (120, 90, 60))
    layout = {
        "ssvtp": [("images_rgb/image_437_rgb.jpg", "images_tac/image_437_tac.jpg",
                   "images_tac/image_437_tac.jpg", "smooth, glossy, patterned")],
        "hct/data2": [("67-1702595521.949646/vision/72-0.0223.jpg",
                       "67-1702595521.949646/tactile/72-0.0223.jpg",
                       "67-1702595521.949646/tactile/0-0.0001.jpg", "hard, smooth, flat")],
    }
    for sub, rows in layout.items():
        d = root / sub
        for row in rows:
            for rel in row[:3]:
                (d / rel).parent.mkdir(parents=True, exist_ok=True)
                img.save(d / rel)
        with open(d / "test.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["url", "tactile_url", "background", "caption"])
            w.writerows(rows)
    records = read_tvl(root, "test")
    assert [r.subset for r in records] == ["hct/data2", "ssvtp"]
    assert records[1].vision == root / "ssvtp/images_rgb/image_437_rgb.jpg"
    assert records[0].caption == "hard, smooth, flat" and records[0].meta is None
    assert all(r.vision.is_file() and r.tactile.is_file() for r in records)
    with pytest.raises(DataNotFoundError, match="train.csv"):
        read_tvl(root, "train")


def test_reader_errors_are_clear(tmp_path):
    with pytest.raises(DataNotFoundError, match="does not exist"):
        read_tvl(tmp_path / "nope")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "test.csv").write_text("a,b,c,d\nonly,three,cols\n")
    with pytest.raises(DataError, match="4 columns"):
        read_tvl(bad)


def test_small_train_split_and_both_subsets(tmp_path):
    counts = write_split(WorldConfig(seed=3, structured_fraction=0.3), tmp_path, "train", n=40,
                         workers=1, progress=False)
    assert sum(counts.values()) == 40 and counts["structured"] > 0 and counts["wild"] > 0
    assert len(read_tvl(tmp_path, "train")) == 40


def test_bad_arguments_leave_nothing_behind(tmp_path):
    out = tmp_path / "new"
    with pytest.raises(ConfigError):
        write_split(WorldConfig(), out, "train", n=-1, progress=False)
    with pytest.raises(ConfigError):
        write_split(WorldConfig(), out, "validation", progress=False)
    with pytest.raises(ConfigError, match="402"):
        write_split(WorldConfig(), out, "test", n=10, progress=False)
    assert not out.exists()


def test_interrupted_write_leaves_nothing_half_written(tmp_path, monkeypatch):
    import ratouch.world.dataset as ds

    calls = {"n": 0}
    real = ds._write_chunk

    def failing(args):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(args)

    monkeypatch.setattr(ds, "_write_chunk", failing)
    out = tmp_path / "data"
    with pytest.raises(KeyboardInterrupt):
        write_split(WorldConfig(), out, "train", n=60, workers=1, progress=False)
    assert not out.exists()
    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "keep.txt").write_text("mine")
    with pytest.raises(KeyboardInterrupt):
        calls["n"] = 0
        write_split(WorldConfig(), existing, "train", n=60, workers=1, progress=False)
    assert sorted(os.listdir(existing)) == ["keep.txt"]


def test_a_publish_killed_midway_names_the_command_with_its_size(tmp_path, monkeypatch):
    """The command that finishes an interrupted publish is the one that was started: its
    --n, --seed and regime included (a plain `--split train` would build 20,000 pairs)."""
    import ratouch.world.dataset as ds
    from ratouch.world.scarcity import ScarceRegime

    real = ds.publish

    def dying(staging, folder, names):
        names = list(names)
        real(staging, folder, [n for n in names if n.endswith(".csv")][:1])
        raise KeyboardInterrupt  # killed with a CSV in place, its images not

    monkeypatch.setattr(ds, "publish", dying)
    out = tmp_path / "tvl"
    with pytest.raises(KeyboardInterrupt):
        write_split(WorldConfig(seed=4), out, "train", n=12, workers=1, progress=False,
                    regime=ScarceRegime(regime="full", seed=4, draw=2))
    with pytest.raises(DataError) as e:
        read_tvl(out, "train")
    assert f"`ratouch world build --out {out.resolve()} --split train --n 12 --seed 4 " \
           "--regime full --draw 2`" in str(e.value)
