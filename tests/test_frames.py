"""`ratouch eval frames`: real tactile frames read for what they are, on a user's folder and
on the real frames the project can see (Taxim's real presses and backgrounds, the reference
DIGIT frames); and the contact signal that cannot be fooled (a frame equal to its background,
a score that is not a number)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from ratouch.cli import main
from ratouch.errors import DataNotFoundError
from ratouch.eval.frames import (
    contact_region,
    firmness,
    format_frames,
    frames_in,
    overlaps,
    read_frames,
    summarise,
    taxim_frames,
)
from ratouch.eval.report import git_commit
from ratouch.world.taxim_optics import real_presses


def test_firmness_reads_the_judges_soft_and_hard_words():
    assert firmness("soft, fuzzy, warm") == "soft"
    assert firmness("hard, smooth, cold") == "hard"
    assert firmness("soft, rigid") == "both"
    assert firmness("smooth, textured") == "neither"


def test_contact_region_finds_a_real_press_on_its_touch():
    d = real_presses("gelsight_mini")
    for i in range(0, len(d["frames"]), 6):
        region = contact_region(d["frames"][i], d["background"])
        assert overlaps(region, tuple(d["centres"][i]), float(d["radii"][i]))
    assert not contact_region(d["background"], d["background"]).any()


def test_frames_in_reads_a_folder_and_leaves_the_background_out(tmp_path):
    d = real_presses("gelsight_mini")
    for i in range(2):
        Image.fromarray(d["frames"][i]).save(tmp_path / f"press{i}.png")
    Image.fromarray(d["background"]).save(tmp_path / "bg.png")
    frames = frames_in(tmp_path, tmp_path / "bg.png")
    assert [f.name for f in frames] == ["press0.png", "press1.png"]
    assert all(f.background is not None and f.background.shape == f.frame.shape for f in frames)
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataNotFoundError, match="no image file"):
        frames_in(tmp_path / "empty")
    with pytest.raises(DataNotFoundError, match="not a folder"):
        frames_in(tmp_path / "missing")


@pytest.fixture(scope="module")
def mini_rows(pipeline):
    return read_frames(pipeline, taxim_frames("gelsight_mini"), k=3)


def test_a_blank_sensor_read_against_itself_is_no_contact_by_construction(mini_rows):
    row = next(r for r in mini_rows if r["frame"].endswith("against itself"))
    assert row["state"] == "no contact"
    assert row["contact"] is None or np.isfinite(row["contact"])
    assert row["ra_touch"] == ""  # nothing to describe
    # the noise floor decided (the contact model scores a zero change above its threshold),
    # and the table says so instead of printing that score
    assert row["within_noise"]["change"] < row["within_noise"]["floor"]
    line = next(x for x in format_frames(mini_rows).splitlines() if "against itself" in x)
    assert " noise " in line


def test_real_presses_are_detected_on_their_touch(mini_rows):
    s = summarise(mini_rows)
    assert s["presses"] == 24
    assert s["presses_detected"] == 24, [r["state"] for r in mini_rows]
    assert s["presses_region_on_touch"] == 24
    assert all(r["sensor"] == "mini" for r in mini_rows)
    # a rigid ball is a firm press by its shape: the touch-only reading is the paper's tactile
    # query's (docs/geometry.md, "The touch-only reading routed by the press's regime")
    for r in mini_rows:
        if r["known_touch"]:
            assert r["reading_query"] == "tactile" and r["reading"] == r["reading_tactile"]
            assert r["shape"]["regime"] == "world" and r["reading_adapted"]


def test_a_not_a_number_score_is_never_contact(pipeline, monkeypatch):
    frame = real_presses("gelsight_mini")["frames"][0]
    monkeypatch.setattr(type(pipeline.trust), "contact_score", lambda *a, **k: float("nan"))
    state, _ = pipeline.trust.contact_state(frame, None)
    assert state == "uncertain"


def test_eval_frames_cli_on_a_folder(tmp_path, capsys, shipped_corpus):
    d = real_presses("gelsight")
    Image.fromarray(d["frames"][3]).save(tmp_path / "press.png")
    Image.fromarray(d["background"]).save(tmp_path / "blank.png")
    Image.fromarray(d["background"]).save(tmp_path / "bg.png")
    assert main(["eval", "frames", str(tmp_path), "--background", str(tmp_path / "bg.png"),
                 "--json", "--k", "2", "--corpus", str(shipped_corpus)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["command"].startswith(f"ratouch eval frames {tmp_path} --background ")
    assert out["encoder"] == "default-s" and out["corpus"] == str(shipped_corpus)
    assert len(out["measured"]) == 10 and out["seconds"] >= 0
    assert out["commit"] == git_commit()  # the code it was read with
    rows = {r["frame"]: r for r in out["frames"]}
    assert set(rows) == {"press.png", "blank.png"}
    assert rows["press.png"]["state"] == "contact" and len(rows["press.png"]["neighbours"]) == 2
    assert rows["blank.png"]["state"] == "no contact"
    assert main(["eval", "frames"]) == 2  # a folder or --real
    assert main(["eval", "frames", str(tmp_path), "--alone"]) == 2  # --alone reads Taxim's


def test_taxims_presses_read_without_their_background(pipeline):
    """`eval frames --real --alone`: each press also without its background, counted apart
    (detected, refused, read hard) from the presses read against it."""
    frames = taxim_frames("gelsight_mini", alone=True)
    alone = [f for f in frames if f.name.endswith(" alone") and " press " in f.name]
    assert len(alone) == len(real_presses("gelsight_mini")["frames"])
    assert all(f.background is None and f.centre is not None for f in alone)
    with_bg = [f for f in frames if " press " in f.name and f not in alone][:2]
    rows = read_frames(pipeline, with_bg + alone[:3], k=3)
    s = summarise(rows)
    assert s["presses"] == 2 and s["presses_alone"] == 3
    assert s["presses_alone_detected"] + s["presses_alone_refused"] <= 3
    assert s["presses_alone_read_hard"] <= 3 - s["presses_alone_refused"]
    assert "presses_alone" not in summarise(rows[:2])
