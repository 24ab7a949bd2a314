"""Trust signals and bounded uploads, as a user of the pipeline meets them: a frame with nothing
pressed into the gel, an input unlike the world, a huge or hostile image file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ratouch.errors import ConfigError, DataError
from ratouch.images import QUERY_MAX_SIDE, to_rgb_array
from ratouch.model.trust import (
    UNIFORM_SPREAD,
    ContactModel,
    Novelty,
    TrustCalibration,
    contact_features,
    image_spread,
)
from ratouch.paths import REPO, trust_calibration
from ratouch.serve.request import QueryRequest
from ratouch.world.config import WorldConfig
from ratouch.world.sampler import World

REFERENCE = REPO.parent / "shared" / "data" / "reference_tactile"


@pytest.fixture(scope="module")
def no_contact_world() -> World:
    return World(WorldConfig(seed=0).with_stress(no_contact=1.0))


def test_shipped_calibration_meets_its_targets():
    cal = TrustCalibration.load(trust_calibration("default-s"))
    m = cal.meta["measured"]
    for key in ("visual_false_alarm_test", "tactile_false_alarm_test",
                "visual_prior_false_alarm_test", "contact_miss_test", "contact_miss_test_bg",
                "contact_false_alarm_test", "contact_false_alarm_test_bg"):
        assert m[key] <= 0.05, key
    for fam in cal.meta["families"]:  # every sensor family, with and without its background
        for key in ("contact_miss_test", "contact_false_alarm_test"):
            assert m[f"{key}_{fam}"] <= 0.1 and m[f"{key}_bg_{fam}"] <= 0.1, (key, fam)
    assert cal.meta["validation"].startswith("train[")  # thresholds never set on the test split
    assert cal.visual_prior is not None  # visual novelty in the prior's feature space


def test_no_contact_frame_gets_no_material_description(pipeline, no_contact_world):
    s = no_contact_world.sample("test", 33)
    assert not s.contact
    r = pipeline.query(s.visual, s.tactile, box=s.box)
    assert r["trust"]["tactile"]["no_contact"] is True
    assert r["description"] == {"ra_touch": "", "baseline": ""}
    said = next(w for w in r["warnings"] if w.startswith("no contact detected"))
    # read alone, the user is told what finds a shallow press: the sensor's background
    assert said.endswith("give the sensor's no-contact frame (background): against it, "
                         "shallow and broad presses are found")
    json.dumps(r)
    # with the sensor's own background the check compares against it, and says so
    bg = no_contact_world.background_image(s.sensor)
    r = pipeline.query(s.visual, s.tactile, box=s.box, background=bg)
    assert r["trust"]["tactile"]["background"] is True and r["trust"]["tactile"]["no_contact"]
    said = next(w for w in r["warnings"] if w.startswith("no contact detected"))
    assert "against the background frame" in said and "give the sensor's" not in said


def test_a_blank_or_uniform_photo_is_never_familiar(pipeline, world, tmp_path):
    white = tmp_path / "white.png"
    Image.new("RGB", (6000, 6000), (255, 255, 255)).save(white)  # the upload
    r = pipeline.query(white, None)
    assert r["trust"]["visual"]["uniform"] and r["trust"]["visual"]["novel"]
    assert any(w.startswith("uniform image: nothing to recognise") for w in r["warnings"])
    rng = np.random.default_rng(0)
    grey = np.clip(200 + rng.normal(0, 8, (480, 640, 3)), 0, 255).astype(np.uint8)  # noisy
    assert image_spread(grey) < UNIFORM_SPREAD
    for i in (0, 12, 40, 60, 140, 190, 290, 390):  # the app's examples are something
        s = world.sample("test", i)
        r = pipeline.query(s.visual, None, box=s.box)
        assert not r["trust"]["visual"]["uniform"], i
        assert not any(w.startswith("uniform image") for w in r["warnings"])


def test_contact_frame_is_described_and_not_flagged(pipeline, world):
    # test pair 35 (corduroy on a DIGIT); pair 33, glass pressed flat on a Taxim GelSight, is
    # among the GelSight presses the contact check misses (8 % of them, measured in the
    # calibration's meta and reported)
    s = world.sample("test", 35)
    r = pipeline.query(s.visual, s.tactile, box=s.box,
                       background=world.background_image(s.sensor))
    t = r["trust"]
    assert t["tactile"]["no_contact"] is False and t["tactile"]["contact"] > 0
    assert {"novelty", "threshold", "novel"} <= set(t["visual"])
    assert r["description"]["ra_touch"] and r["description"]["baseline"]


@pytest.mark.xfail(strict=True, reason="a known miss, measured: with visual novelty in the "
                   "prior's feature space a 40-px checkerboard scores 1.14 against the 1.60 "
                   "threshold set on world renders (texture-like images, as scikit-image's grass "
                   "and gravel, stay under it); its tactile frame is refused as no contact")
def test_a_checkerboard_is_flagged_as_unlike_the_training_data(pipeline, world):
    s = world.sample("test", 34)
    yy, xx = np.mgrid[0:240, 0:320]
    board = np.repeat((((yy // 40 + xx // 40) % 2) * 255).astype(np.uint8)[..., None], 3, 2)
    r = pipeline.query(board, board, box=(0, 0, 320, 240))
    assert r["trust"]["visual"]["novel"] and r["trust"]["tactile"]["novel"]
    assert sum("unlike the" in w for w in r["warnings"]) == 2
    assert not pipeline.query(s.visual, s.tactile, box=s.box)["trust"]["visual"]["novel"]


def test_background_of_another_size_is_refused(pipeline, world):
    s = world.sample("test", 35)
    with pytest.raises(DataError, match="background image is 50x60"):
        pipeline.query(s.visual, s.tactile, background=np.zeros((60, 50, 3), np.uint8))


def test_huge_tactile_upload_is_reduced_before_any_pixel_work(pipeline, world, tmp_path):
    s = world.sample("test", 36)
    big = np.asarray(Image.fromarray(s.tactile).resize((1800, 2400), Image.BILINEAR))
    Image.fromarray(big).save(tmp_path / "big.png")
    prepared = QueryRequest.decode(s.visual, tmp_path / "big.png", box=s.box)
    assert max(prepared.frame.shape[:2]) == QUERY_MAX_SIDE
    r = pipeline.query(s.visual, tmp_path / "big.png", box=s.box)
    small = pipeline.query(s.visual, s.tactile, box=s.box)
    assert r["trust"]["tactile"]["no_contact"] is False and r["description"]["ra_touch"]
    # the contact score is measured at a fixed resolution: the upload's size hardly moves it
    assert r["trust"]["tactile"]["contact"] == pytest.approx(
        small["trust"]["tactile"]["contact"], rel=0.25)


def test_decompression_bomb_is_refused_with_role_and_size(pipeline, world, tmp_path):
    Image.new("1", (10_000, 6_000)).save(tmp_path / "bomb.png")  # 60 Mpx, a few kB on disk
    s = world.sample("test", 37)
    with pytest.raises(DataError, match=r"tactile image is 10000x6000 .* 60\.0 megapixels"):
        pipeline.query(s.visual, tmp_path / "bomb.png", box=s.box)


def test_jpeg_is_decoded_at_reduced_scale_with_exif_rotation(tmp_path):
    a = np.zeros((1200, 3000, 3), np.uint8)
    a[:, :300] = 255  # a white band on the left: at the top once rotated by EXIF tag 6
    img = Image.fromarray(a)
    exif = img.getexif()
    exif[0x0112] = 6
    img.save(tmp_path / "r.jpg", exif=exif.tobytes())
    out = to_rgb_array(tmp_path / "r.jpg", max_side=QUERY_MAX_SIDE)
    assert out.shape == (320, 128, 3)
    assert out[:20].mean() > 200 and out[-100:].mean() < 30


def test_contact_features_need_a_matching_background(world):
    s = world.sample("test", 38)
    with pytest.raises(DataError, match="background is 10x10"):
        contact_features(s.tactile, np.zeros((10, 10, 3), np.uint8))


def _contact_model(rng, n_features: int) -> ContactModel:
    return ContactModel.fit(rng.normal(1, 1, (60, n_features)), rng.normal(-1, 1, (60, n_features)))


def test_contact_model_separates_what_it_was_fitted_on():
    rng = np.random.default_rng(0)
    model = _contact_model(rng, 4)
    assert (model.score(rng.normal(1, 0.3, (20, 4))) > model.score(rng.normal(-1, 0.3, (20, 4)))
            .max()).mean() > 0.9


def test_calibration_round_trips_and_rejects_other_files(tmp_path):
    rng = np.random.default_rng(0)
    nov = Novelty.fit(rng.normal(size=(100, 8)), rank=3).with_threshold(1.5)
    prior = Novelty.fit(rng.normal(size=(100, 12)), rank=3).with_threshold(2.5)
    plain, with_bg = _contact_model(rng, 16), _contact_model(rng, 18)
    cal = TrustCalibration("enc", nov, nov, plain, with_bg, 2.0, 3.0, prior, {"seed": 0})
    back = TrustCalibration.load(cal.save(tmp_path / "t.json"))
    x = rng.normal(size=(5, 8))
    assert np.allclose(back.visual.score(x), nov.score(x), rtol=1e-4)
    assert back.visual_prior is not None and back.visual_prior.threshold == 2.5
    f = rng.normal(size=(3, 18))
    assert np.allclose(back.contact_bg.score(f), with_bg.score(f), rtol=1e-4, atol=1e-4)
    assert back.contact_threshold == 2.0 and back.meta == {"seed": 0}
    no_prior = TrustCalibration("enc", nov, nov, plain, with_bg, 2.0, 3.0)
    assert TrustCalibration.load(no_prior.save(tmp_path / "n.json")).visual_prior is None
    banded = TrustCalibration("enc", nov, nov, plain, with_bg, 2.0, 3.0, None, {}, 0.01,
                              (1.0, 2.5))
    back = TrustCalibration.load(banded.save(tmp_path / "b.json"))
    assert back.noise_floor == 0.01 and back.uncertain == (1.0, 2.5)
    assert back.uncertain_alone is None
    alone = TrustCalibration("enc", nov, nov, plain, with_bg, 2.0, 3.0,
                             uncertain_alone={"mini": -6.5, "digit": -2.0})
    path = alone.save(tmp_path / "a.json")
    assert TrustCalibration.load(path).uncertain_alone == {"mini": -6.5, "digit": -2.0}
    d = json.loads(path.read_text())
    path.write_text(json.dumps({**d, "uncertain_alone": [-6.5]}))
    with pytest.raises(DataError, match="uncertain_alone must map sensor families"):
        TrustCalibration.load(path)
    second = TrustCalibration("enc", nov, nov, plain, with_bg, 2.0, 3.0,
                              press_alone={"digit": (with_bg, -0.8)})
    back = TrustCalibration.load(second.save(tmp_path / "p.json"))
    assert set(back.press_alone or {}) == {"digit"} and back.press_alone["digit"][1] == -0.8
    assert np.allclose(back.press_alone["digit"][0].score(f), with_bg.score(f), rtol=1e-4,
                       atol=1e-4)
    d = json.loads((tmp_path / "p.json").read_text())
    (tmp_path / "p.json").write_text(json.dumps({**d, "press_alone": [1.0]}))
    with pytest.raises(DataError, match="press_alone must map sensor families"):
        TrustCalibration.load(tmp_path / "p.json")
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(DataError, match="not a trust calibration"):
        TrustCalibration.load(tmp_path / "bad.json")


@pytest.mark.skipif(not REFERENCE.is_dir(), reason="no real reference frames beside the repo")
def test_real_digit_frames_are_never_misread(pipeline):
    """The two real DIGIT frames (never used for calibration): the blank sensor is never
    called a press and the pressed frame never "no contact"; against a background the model
    decides, and the blank read against itself is no contact by construction. Without a
    background both look like none of the rendered sensors, which the trust block says."""
    cal = pipeline.trust
    blank = to_rgb_array(Path(REFERENCE, "digit_tacto_bg_digit_240_320.png"),
                         max_side=QUERY_MAX_SIDE)
    pressed = to_rgb_array(Path(REFERENCE, "digit_aurova_digit_raw.png"), max_side=QUERY_MAX_SIDE)
    assert cal.contact_state(blank)[0] in ("no contact", "uncertain")
    assert cal.contact_state(blank, blank)[0] == "no contact"
    assert cal.contact_state(pressed)[0] in ("contact", "uncertain")
    assert cal.contact_state(pressed, blank)[0] == "contact"
    enc = pipeline.encoders
    out = cal.assess(enc.encode_image([pressed]), enc.encode_tactile([pressed]), pressed)
    assert out["tactile"]["unfamiliar_sensor"]
    assert any("looks like none of the sensors" in w for w in out["warnings"])


@pytest.mark.skipif(not REFERENCE.is_dir(), reason="no real reference frames beside the repo")
@pytest.mark.xfail(strict=True, reason="a known miss, reported in docs/trust.md: with the "
                   "encoders retrained with the real priors the real pressed DIGIT frame's "
                   "tactile novelty is 1.18, under the 1.32 threshold set on world renders (the "
                   "threshold is not tuned to real frames); strict, so a fix shows")
def test_real_pressed_digit_frame_is_flagged_as_unfamiliar(pipeline):
    frame = to_rgb_array(Path(REFERENCE, "digit_aurova_digit_raw.png"), max_side=QUERY_MAX_SIDE)
    enc = pipeline.encoders
    out = pipeline.trust.assess(enc.encode_image([frame]), enc.encode_tactile([frame]), frame)
    assert out["tactile"]["novel"]


@pytest.mark.slow
def test_without_a_background_the_familys_band_answers_a_faint_press_with_a_caveat(
        monkeypatch):
    """`uncertain_alone`: below the threshold but above what the frame's family's blanks
    score alone is "uncertain" (answered with a caveat), lower is "no contact"; a frame that
    looks like none of the families keeps the old rule; above the threshold is contact."""
    import dataclasses

    from ratouch.model import trust as trust_mod

    cal = dataclasses.replace(TrustCalibration.load(trust_calibration("default-s")),
                              uncertain=None, uncertain_alone={"mini": -6.0})
    frame = np.zeros((48, 64, 3), np.uint8)
    look = {"distance": 0.5}
    monkeypatch.setattr(trust_mod, "guess_family", lambda f: ("mini", look["distance"]))
    for score, state in ((-7.0, "no contact"), (-5.0, "uncertain"),
                         (cal.contact_threshold - 1e-3, "uncertain"),
                         (cal.contact_threshold, "contact")):
        monkeypatch.setattr(TrustCalibration, "contact_score", lambda self, f, b=None, s=score: s)
        assert cal.contact_state(frame)[0] == state, score
    monkeypatch.setattr(TrustCalibration, "contact_score", lambda self, f, b=None: -5.0)
    look["distance"] = 9.0                                   # looks like no family's units
    assert cal.contact_state(frame)[0] == "no contact"
    look["distance"] = 0.5
    assert dataclasses.replace(cal, uncertain_alone={"digit": -6.0}).contact_state(frame)[0] \
        == "no contact"                                       # no band for this family


@pytest.mark.slow
def test_without_a_background_the_press_model_widens_the_band(monkeypatch):
    """`press_alone`: a frame of the family below every logit edge is still "uncertain"
    where the family's press model scores it at or above its edge; below both, "no
    contact"; a frame that looks like no family's units, or of a family without a press
    model, is not read by it; contact stays contact."""
    import dataclasses

    from ratouch.model import trust as trust_mod

    class Fixed:
        value = 0.0

        def score(self, feats):
            return np.array([Fixed.value])

    base = TrustCalibration.load(trust_calibration("default-s"))
    cal = dataclasses.replace(base, uncertain=None, uncertain_alone={"mini": -6.0},
                              press_alone={"digit": (Fixed(), -0.5)})
    frame = np.zeros((48, 64, 3), np.uint8)
    look = {"name": "digit", "distance": 0.5}
    monkeypatch.setattr(trust_mod, "guess_family", lambda f: (look["name"], look["distance"]))
    monkeypatch.setattr(TrustCalibration, "contact_score", lambda self, f, b=None: -9.0)
    for value, state in ((-0.6, "no contact"), (-0.5, "uncertain"), (3.0, "uncertain")):
        Fixed.value = value
        assert cal.contact_state(frame)[0] == state, value
    assert cal.alone_band_reading(frame, -9.0) == {"family": "digit", "reading": "press model",
                                                   "score": 3.0, "edge": -0.5}
    assert cal.alone_band_reading(frame, -9.0, ("mini", 0.5)) is None     # -9 < -6
    assert cal.alone_band_reading(frame, -5.0, ("mini", 0.5))["reading"] == "contact model"
    look["distance"] = 9.0                                   # looks like no family's units
    assert cal.contact_state(frame)[0] == "no contact"
    look.update(name="mini", distance=0.5)                   # the logit band only, -9 < -6
    assert cal.contact_state(frame)[0] == "no contact"
    monkeypatch.setattr(TrustCalibration, "contact_score",
                        lambda self, f, b=None: cal.contact_threshold)
    look["name"] = "digit"
    Fixed.value = -5.0
    assert cal.contact_state(frame)[0] == "contact"


def test_with_alone_band_fits_a_press_model_within_the_blanks_share():
    """`with_alone_band` on the shipped calibration at small sizes: the DIGIT gets a press
    model whose edges together call at most the allowed share of its held-out blanks
    "uncertain"; the GelSight keeps `alone_band`'s logit edge and its press model calls at
    most that share more of them (a share of its own); the Mini keeps `alone_band`'s band;
    and the record says what was compared."""
    from ratouch.train.trust import (
        OWN_SHARE_FAMILIES,
        PRESS_MODEL_FAMILIES,
        UNCERTAIN_SHARE,
        _alone_blanks,
        alone_band,
        validation_blanks,
        validation_presses,
        with_alone_band,
    )

    assert OWN_SHARE_FAMILIES == ("gelsight",) and PRESS_MODEL_FAMILIES == ("digit", "gelsight")
    cal = TrustCalibration.load(trust_calibration("default-s"))
    blanks, presses = validation_blanks(5, n=90), validation_presses(5, n=90)
    out = with_alone_band(cal, n=100, seed=5, world_blanks=blanks, n_presses=40, n_check=20,
                          world_presses=presses)
    rec = out.meta["alone_band"]["families"]
    assert set(rec) == {"digit", "gelsight"}
    assert out.meta["alone_band"]["second_reading_tried_on"] == ["digit", "gelsight"]
    logit_band = alone_band(cal, 100, 5, blanks)
    for fam in ("gelsight", "mini"):        # the GelSight's logit edge is not moved
        assert (out.uncertain_alone or {}).get(fam) == logit_band.get(fam)
    assert rec["gelsight"]["blank_share_allowed"] == 2 * UNCERTAIN_SHARE
    assert rec["digit"]["blank_share_allowed"] == UNCERTAIN_SHARE
    for fam in ("digit", "gelsight"):
        answered = rec[fam]["answered_on_check_presses"]
        if fam not in (out.press_alone or {}):
            continue                        # kept only where it answers more check presses
        assert answered["logit_and_press_model"] > answered["logit"]
        held = _alone_blanks(100, 5, blanks, slice(1, None, 2))[fam]
        model, edge = out.press_alone[fam]
        low = (out.uncertain_alone or {}).get(fam, np.inf)
        by_logit = np.array([cal.contact_score(f) >= low for f in held])
        by_press = np.array([float(model.score(contact_features(f))[0]) >= edge
                             for f in held])
        allowed = np.floor(UNCERTAIN_SHARE * len(held))
        if fam in OWN_SHARE_FAMILIES:       # the press model's own share, beyond the logit's
            assert np.sum(by_press & ~by_logit) <= allowed
        else:
            assert np.sum(by_logit | by_press) <= allowed
    assert "gelsight" in (out.press_alone or {})  # its press model answers more presses
    assert out.contact_threshold == cal.contact_threshold
    assert {k: v for k, v in out.meta.items() if k != "alone_band"} == \
        {k: v for k, v in cal.meta.items() if k != "alone_band"}


def test_alone_band_sits_above_the_familys_blanks_and_below_the_threshold(tmp_path, capsys,
                                                                          monkeypatch):
    """`alone_band` on the shipped calibration (a few blank renders per family), and `ratouch
    train trust --alone-band --out F`, which writes the calibration with its band and nothing
    else changed."""
    from ratouch.cli import main
    from ratouch.train.trust import alone_band, validation_blanks, validation_presses
    from ratouch.world.presses import render_blank_pair

    cal = TrustCalibration.load(trust_calibration("default-s"))
    world = validation_blanks(4, n=60)      # the world's own no-contact renders
    band = alone_band(cal, n=12, seed=4, world_blanks=world)
    assert band and set(band) <= {"digit", "gelsight", "mini"}
    rng = np.random.default_rng(9)
    for fam, low in band.items():
        assert low < cal.contact_threshold
        blanks = [cal.contact_score(render_blank_pair(fam, rng)[0]) for _ in range(4)]
        assert np.median(blanks) < low + 1.0  # the band sits at the top of the blanks
        own = [cal.contact_score(f) for f, name in zip(world["frames"], world["families"])
               if name == fam]
        assert np.mean(np.array(own) < low) >= 0.9  # and above most of the world's blanks
    out = tmp_path / "t.json"
    import functools

    from ratouch.cli import train as cli_train
    from ratouch.train.trust import with_alone_band
    # the command's plumbing at small sizes (the full sizes take two minutes)
    monkeypatch.setattr(cli_train, "with_alone_band", functools.partial(
        with_alone_band, n=12, world_blanks=world, n_presses=20, n_check=10,
        world_presses=validation_presses(4, n=60)))
    assert main(["train", "trust", "--alone-band", "--seed", "4", "--out", str(out)]) == 0
    written = TrustCalibration.load(out)
    printed = json.loads(capsys.readouterr().out)
    assert (written.uncertain_alone or {}) == (printed["uncertain_alone"] or {})
    assert sorted(written.press_alone or {}) == printed["press_alone"]
    assert written.contact_threshold == cal.contact_threshold
    assert {k: v for k, v in written.meta.items() if k != "alone_band"} == \
        {k: v for k, v in cal.meta.items() if k != "alone_band"}
    assert written.meta["alone_band"] == printed["alone_band"]


def test_calibration_is_reproducible(tmp_path):
    """`calibrate` with the same seed gives the same thresholds (small sizes)."""
    from ratouch.encoders.factory import create_model
    from ratouch.train.trust import TrustConfig, calibrate

    enc = create_model("default-s")
    cfg = TrustConfig(n_reference=120, n_validation=100, n_everyday=8, n_alone_blanks=20,
                      n_alone_presses=12, n_alone_check=6, n_unfamiliar=30, n_test=60)
    a, b = calibrate(enc, cfg, progress=False), calibrate(enc, cfg, progress=False)
    assert a.meta["test"] == "test[0:60] (measured only)" == b.meta["test"]
    assert a.meta["measured"] == b.meta["measured"]
    with pytest.raises(ConfigError, match="n_test"):
        TrustConfig(n_test=0)
    assert a.contact_unfamiliar[1] == b.contact_unfamiliar[1]  # opt-in: fitted when asked
    assert "train[0:30]" in a.meta["unfamiliar_contact"]["fit"]
    assert calibrate.__defaults__[0].n_unfamiliar == 0  # and not by default (not shipped)
    assert a.contact_threshold == b.contact_threshold
    assert a.uncertain_alone == b.uncertain_alone and a.uncertain_alone  # on 20 blanks
    assert a.meta["alone_band"] == b.meta["alone_band"]
    assert {k: e for k, (_, e) in (a.press_alone or {}).items()} == \
        {k: e for k, (_, e) in (b.press_alone or {}).items()}
    assert a.visual.threshold == b.visual.threshold
    assert a.meta["measured"]["contact_false_alarm_test_bg"] <= 0.1


def test_huge_visual_crop_matches_the_full_resolution_crop(tmp_path):
    """A crop reduced inside PIL (bounded work) shows what the full-resolution crop shows."""
    from ratouch.images import crop_box, fit_within

    rng = np.random.default_rng(0)
    small = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    big = np.asarray(Image.fromarray(small).resize((4000, 3000), Image.NEAREST))
    Image.fromarray(big).save(tmp_path / "big.jpg", quality=95)
    box = (1000, 500, 2600, 2100)
    fast = crop_box(tmp_path / "big.jpg", box, max_side=QUERY_MAX_SIDE)
    slow = fit_within(crop_box(to_rgb_array(tmp_path / "big.jpg"), box), QUERY_MAX_SIDE)
    assert fast.shape == slow.shape == (320, 320, 3)
    assert np.abs(fast.astype(int) - slow.astype(int)).mean() < 8
    with pytest.raises(DataError, match="outside the 4000x3000"):
        crop_box(tmp_path / "big.jpg", (5000, 5000, 5100, 5100), max_side=QUERY_MAX_SIDE)


# ------------------------------------------------- a sensor unlike every rendered unit, alone

def _small_unfamiliar(cal: TrustCalibration) -> TrustCalibration:
    """`with_unfamiliar_contact` on the shipped calibration at small sizes."""
    from ratouch.train.trust import validation_blanks, validation_presses, with_unfamiliar_contact

    return with_unfamiliar_contact(cal, n=40, seed=6, val_presses=validation_presses(6, n=60),
                                   val_blanks=validation_blanks(6, n=60), n_validation=60)


@pytest.fixture(scope="module")
def unfamiliar_cal() -> TrustCalibration:
    return _small_unfamiliar(TrustCalibration.load(trust_calibration("default-s")))


def test_unfamiliar_view_changes_the_sensors_look_and_keeps_the_press():
    """A view keeps the frame's size and where things are; its colours lie beyond every
    rendered unit for most frames; the same stream gives the same view."""
    from ratouch.world.sensors import WITHHOLD_LIMIT, guess_family, unfamiliar_view

    world = World(WorldConfig(seed=0))
    frames = [world.sample("test", i).tactile for i in range(6)]
    views = [unfamiliar_view(f, np.random.default_rng(i)) for i, f in enumerate(frames)]
    assert all(v.shape == f.shape and v.dtype == np.uint8 for v, f in zip(views, frames))
    assert sum(guess_family(v)[1] > WITHHOLD_LIMIT for v in views) >= 4
    assert all(guess_family(f)[1] <= WITHHOLD_LIMIT for f in frames)
    again = unfamiliar_view(frames[0], np.random.default_rng(0))
    assert np.array_equal(again, views[0])


def test_colour_blind_features_ignore_channel_order_and_brightness():
    """`contact_features_free`: a frame with its channels reordered reads the same, and one
    made darker reads nearly the same where the colour-aware features shift by the gain."""
    from ratouch.model.trust import contact_features_free

    frame = World(WorldConfig(seed=0)).sample("test", 3).tactile
    free = contact_features_free(frame)
    assert free.shape == (13,) and np.isfinite(free).all()
    assert np.allclose(contact_features_free(frame[..., [2, 0, 1]]), free, atol=1e-5)
    dark = (frame.astype(np.float64) * 0.6).round().astype(np.uint8)
    plain, plain_dark = contact_features(frame), contact_features(dark)
    assert abs((plain_dark[0] - plain[0]) - np.log(0.6)) < 0.1  # the band level moves by the gain
    assert np.max(np.abs(contact_features_free(dark) - free)[[0, 1, 4, 5, 8, 9]]) < 0.1


def test_colour_blind_contact_reads_only_frames_beyond_every_rendered_unit(unfamiliar_cal,
                                                                           tmp_path):
    """Fitted small: the model and its threshold are kept through save and load; a frame
    beyond the limit alone is decided by it, a frame within the limit and any frame with a
    background are read as before; the trust block names the model and says it is a guess."""
    from ratouch.world.sensors import WITHHOLD_LIMIT, guess_family, unfamiliar_view

    cal = unfamiliar_cal
    shipped = TrustCalibration.load(trust_calibration("default-s"))
    assert shipped.contact_unfamiliar is None  # measured, not shipped (docs/geometry.md)
    model, thr = cal.contact_unfamiliar
    assert thr == cal.meta["unfamiliar_contact"]["threshold"]
    back = TrustCalibration.load(cal.save(tmp_path / "t.json"))
    assert back.contact_unfamiliar[1] == thr
    assert np.allclose(back.contact_unfamiliar[0].coef, model.coef)
    world = World(WorldConfig(seed=0))
    s = world.sample("test", 5)
    rng = np.random.default_rng(2)
    view = next(v for v in (unfamiliar_view(s.tactile, rng) for _ in range(20))
                if guess_family(v)[1] > WITHHOLD_LIMIT)
    state, score = cal.contact_state(view)
    assert score == pytest.approx(cal.unfamiliar_score(view))
    assert state == ("contact" if score >= thr else "no contact")
    assert shipped.contact_state(view)[1] == pytest.approx(shipped.contact_score(view))
    # within the limit, and with a background, nothing changes
    assert cal.contact_state(s.tactile) == shipped.contact_state(s.tactile)
    bg = world.background_image(s.sensor)
    assert cal.contact_state(view, bg) == shipped.contact_state(view, bg)
    V = np.zeros((1, cal.visual.mean.shape[0]))
    T = np.zeros((1, cal.tactile.mean.shape[0]))
    block = cal.assess(V, T, view)
    assert block["tactile"]["contact_model"] == "colour-blind"
    assert block["tactile"]["contact_threshold"] == thr
    assert any("blind to its colours" in w for w in block["warnings"])
    assert shipped.assess(V, T, view)["tactile"]["contact_model"] == "disc-press"
    assert cal.assess(V, T, view, bg)["tactile"]["contact_model"] is None
    with pytest.raises(ConfigError, match="--unfamiliar"):
        shipped.unfamiliar_score(view)


def test_a_frame_beyond_every_rendered_unit_read_alone_is_never_called_contact(pipeline,
                                                                                world):
    """Without the colour-blind model (as shipped), a frame beyond every rendered unit read
    alone that the disc-press model scores above its threshold is "uncertain", not "contact":
    the score is read from colours the model was never fitted on (docs/geometry.md). The same
    press as rendered is "contact"; the warning says why; with its background the structured
    check decides as before."""
    from ratouch.world.sensors import WITHHOLD_LIMIT, guess_family, unfamiliar_view

    cal = pipeline.trust
    assert cal.contact_unfamiliar is None
    rng = np.random.default_rng(9)
    for i in range(40):
        s = world.sample("test", i)
        views = [unfamiliar_view(s.tactile, rng) for _ in range(5)]
        far = [v for v in views if guess_family(v)[1] > WITHHOLD_LIMIT
               and cal.contact_score(v) >= cal.contact_threshold]
        if far and cal.contact_state(s.tactile)[0] == "contact":
            break
    else:
        pytest.fail("no test press with a view beyond the limit scoring contact")
    view = far[0]
    state, score = cal.contact_state(view)
    assert state == "uncertain" and score == pytest.approx(cal.contact_score(view))
    V = np.zeros((1, cal.visual.mean.shape[0]))
    T = np.zeros((1, cal.tactile.mean.shape[0]))
    block = cal.assess(V, T, view)
    assert block["tactile"]["uncertain"] and block["tactile"]["unfamiliar_sensor"]
    assert any(w.startswith("contact uncertain") and "blank frames score as high as presses"
               in w for w in block["warnings"])
    # a frame within the limit above the threshold: contact, as before
    assert cal.assess(V, T, s.tactile)["tactile"]["state"] == "contact"


def test_train_trust_unfamiliar_writes_only_that_model(tmp_path, capsys, monkeypatch):
    """`ratouch train trust --unfamiliar --out F` (at small sizes) adds the model and its
    record and changes nothing else; asked for with --alone-band it is a usage error."""
    from ratouch.cli import main
    from ratouch.cli import train as cli_train

    shipped = TrustCalibration.load(trust_calibration("default-s"))
    monkeypatch.setattr(cli_train, "with_unfamiliar_contact",
                        lambda cal, seed, false_alarm: _small_unfamiliar(cal))
    out = tmp_path / "t.json"
    assert main(["train", "trust", "--unfamiliar", "--out", str(out)]) == 0
    written = TrustCalibration.load(out)
    printed = json.loads(capsys.readouterr().out)
    assert written.contact_unfamiliar is not None
    assert printed["unfamiliar_contact"] == written.meta["unfamiliar_contact"]
    assert written.contact_threshold == shipped.contact_threshold
    assert written.uncertain_alone == shipped.uncertain_alone
    assert {k: v for k, v in written.meta.items() if k != "unfamiliar_contact"} == shipped.meta
    assert main(["train", "trust", "--unfamiliar", "--alone-band", "--out",
                 str(tmp_path / "u.json")]) == 2
    assert not (tmp_path / "u.json").exists()


def test_a_frame_called_its_background_within_noise_says_so(pipeline, world):
    """A frame equal to its background is "no contact" by the noise floor although the
    contact model, never fitted on a zero change, scores it above its threshold: the block
    says which rule decided ("within_noise": the change and the floor) and the warning does
    not claim the score was below the threshold."""
    enc = pipeline.encoders
    for i in range(3):
        s = world.sample("test", i)
        bg = world.background_image(s.sensor)
        out = pipeline.trust.assess(enc.encode_image([s.crop]), enc.encode_tactile([bg], [bg]),
                                    bg, bg)
        t = out["tactile"]
        assert t["state"] == "no contact"
        warning = next(w for w in out["warnings"] if w.startswith("no contact detected"))
        if t["contact"] >= t["contact_threshold"]:
            noise = t["within_noise"]
            assert noise["change"] < noise["floor"] == round(pipeline.trust.noise_floor, 4)
            assert "within the sensor's noise" in warning
            assert f"contact {t['contact']} <" not in warning
        else:
            assert "within_noise" not in t
    pressed = world.sample("test", 0)
    bg = world.background_image(pressed.sensor)
    out = pipeline.trust.assess(enc.encode_image([pressed.crop]),
                                enc.encode_tactile([pressed.tactile], [bg]), pressed.tactile, bg)
    assert out["tactile"]["state"] == "contact" and "within_noise" not in out["tactile"]
