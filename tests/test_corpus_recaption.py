"""`ratouch corpus recaption`: a folder of one's own images (FOLDER/<class>/<image>) into an
ImageNet-T corpus that `corpus build` embeds; bad input refused with nothing written; and
`ratouch eval recaption`'s agreement figures."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from ratouch.cli import main
from ratouch.corpus.imagenet_t import load_corpus, read_image_folder
from ratouch.corpus.recaption import validate_caption
from ratouch.errors import ConfigError
from ratouch.eval.recaption import (
    format_recaption_agreement,
    recaption_agreement,
    world_adjectives,
)
from ratouch.vocabulary import TVL_ADJECTIVES


def _folder(root, names=(("teddy_bear", "a.png"), ("teddy_bear", "b.jpg"),
                         ("frying_pan", "c.png"))):
    for i, (cls, name) in enumerate(names):
        (root / cls).mkdir(parents=True, exist_ok=True)
        Image.fromarray(np.full((24, 24, 3), 40 * i, np.uint8)).save(root / cls / name)
    return root


def test_folder_layout_gives_class_names(tmp_path):
    rows = read_image_folder(_folder(tmp_path / "imgs"))
    assert [(r[1], r[2]) for r in rows] == [("frying pan", "a photo of a frying pan"),
                                            ("teddy bear", "a photo of a teddy bear"),
                                            ("teddy bear", "a photo of a teddy bear")]


def test_recaption_offline_then_build_embeds_it(tmp_path, capsys):
    images, out = _folder(tmp_path / "imgs"), tmp_path / "corpus"
    assert main(["corpus", "recaption", "--images", str(images), "--out", str(out),
                 "--recaptioner", "offline"]) == 0
    manifest, entries = load_corpus(out)
    assert manifest["size"] == 3 and manifest["captioner"] == "offline"
    assert sorted(e.class_name for e in entries) == ["frying pan", "teddy bear", "teddy bear"]
    assert all(validate_caption(e.caption) for e in entries)
    assert "corpus build" in capsys.readouterr().err
    # the next step: `corpus build` finds this corpus (kept, not rebuilt) and embeds it
    assert main(["corpus", "build", "--out", str(out), "--from-list", str(images),
                 "--captioner", "offline", "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert "already holds this corpus (3 entries): kept" in captured.err
    built = json.loads(captured.out.strip().splitlines()[-1])
    assert built["resumed"] and load_corpus(out)[1] == entries
    assert list((out / "embeddings").rglob("*.npy"))


@pytest.mark.slow
def test_recaption_with_smollm2_end_to_end(tmp_path, capsys):
    images, out = _folder(tmp_path / "imgs"), tmp_path / "corpus"
    assert main(["corpus", "recaption", "--images", str(images), "--out", str(out)]) == 0
    manifest, entries = load_corpus(out)
    assert manifest["captioner"] == "smollm2" and manifest["size"] == 3
    assert manifest["captioner_stats"]["n_captions"] == 3
    for e in entries:
        words = validate_caption(e.caption)
        assert all(w in TVL_ADJECTIVES for w in words)
    # the two teddy bears have the same class and description: the same caption
    bears = [e.caption for e in entries if e.class_name == "teddy bear"]
    assert bears[0] == bears[1]
    assert main(["corpus", "build", "--out", str(out), "--from-list", str(images),
                 "--captioner", "smollm2", "--no-embed"]) == 0
    assert "kept" in capsys.readouterr().err


def _refused(argv, capsys, needle, out):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("ratouch: error:") and needle in err, err
    assert not out.exists()


def test_bad_folders_are_refused_and_nothing_is_written(tmp_path, capsys):
    out = tmp_path / "corpus"
    base = ["corpus", "recaption", "--out", str(out), "--recaptioner", "offline", "--images"]
    _refused([*base, str(tmp_path / "nowhere")], capsys, "does not exist", out)
    (tmp_path / "empty").mkdir()
    _refused([*base, str(tmp_path / "empty")], capsys, "holds no image", out)
    loose = tmp_path / "loose"
    loose.mkdir()
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(loose / "x.png")
    _refused([*base, str(loose)], capsys, "subfolder named after its class", out)
    broken = _folder(tmp_path / "broken")
    (broken / "teddy_bear" / "z.png").write_bytes(b"not an image at all")
    _refused([*base, str(broken)], capsys, "z.png is unreadable", out)
    (tmp_path / "file.png").write_bytes(b"x")
    _refused([*base, str(tmp_path / "file.png")], capsys, "not a folder", out)


def test_an_existing_corpus_is_not_overwritten(tmp_path, capsys):
    images, out = _folder(tmp_path / "imgs"), tmp_path / "corpus"
    argv = ["corpus", "recaption", "--images", str(images), "--out", str(out),
            "--recaptioner", "offline"]
    assert main(argv) == 0
    before = (out / "manifest.json").read_bytes()
    assert main(argv) == 2
    assert "already holds a corpus" in capsys.readouterr().err
    assert (out / "manifest.json").read_bytes() == before


def test_unknown_recaptioner_is_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["corpus", "recaption", "--images", str(tmp_path), "--out", str(tmp_path / "o"),
              "--recaptioner", "gpt"])
    assert e.value.code == 2


def test_ray_engine_refuses_smollm2(tmp_path):
    from ratouch.corpus.recaption import RecaptionConfig
    from ratouch.distributed.ray_corpus import build_corpus_ray

    with pytest.raises(ConfigError, match="local only"):
        build_corpus_ray(tmp_path / "c", 10, recaption=RecaptionConfig(backend="smollm2"))


def test_agreement_of_the_offline_recaptioner():
    r = recaption_agreement(["offline"], n=12, seed=0)
    s = r["systems"]["offline"]
    assert r["n"] == 12 and 0 < r["reference_in_tvl"] <= 1
    assert s["f1"][1] <= s["f1"][0] <= s["f1"][2] and 0 < s["f1"][0] <= 1
    assert 1 <= s["judge"][1] <= s["judge"][0] <= s["judge"][2] <= 10
    assert "offline" in format_recaption_agreement(r)
    assert len(world_adjectives("oak")) == 5
    with pytest.raises(ConfigError, match="gpt"):
        recaption_agreement(["gpt"], n=2)
