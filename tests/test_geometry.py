"""Touch read as geometry: the Poisson integration, the drift removal, the shipped lookups on
Taxim's held-out real ball presses, contact by structured change on everyday-press renders,
and `ratouch train geometry` / `ratouch eval presses` through the CLI."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from ratouch.cli import main
from ratouch.errors import DataError, DataNotFoundError
from ratouch.model.geometry import (
    FirmnessModel,
    GeometryCalibration,
    RoutedFirmness,
    integrate,
    read_height,
    sphere_gradients,
    working_change,
)
from ratouch.model.trust import background_change
from ratouch.paths import geometry_calibration
from ratouch.train.geometry import HOLD_OUT_EVERY
from ratouch.world.presses import BALL_MM, render_ball, render_blank_pair, render_press
from ratouch.world.sensors import beyond_every_unit, unfamiliar_pair_view
from ratouch.world.taxim_optics import optics, real_presses


@pytest.fixture(scope="module")
def shipped():
    return GeometryCalibration.load(geometry_calibration())


def test_integration_recovers_a_sphere_from_its_gradients():
    g, cap, _ = sphere_gradients((120, 160), (70.0, 55.0), 25.0, 40.0)
    z = integrate(g[..., 0], g[..., 1])
    z = z - np.median(z)
    # the cap's depth and where it lies, within a few percent
    assert abs(z.max() - cap.max()) < 0.1 * cap.max()
    assert np.unravel_index(np.argmax(z), z.shape) == pytest.approx((55, 70), abs=2)
    assert np.corrcoef(z.ravel(), cap.ravel())[0, 1] > 0.98


def test_global_gain_and_offset_are_not_read_as_change():
    rng = np.random.default_rng(0)
    bg = (rng.uniform(0.2, 0.8, (96, 128, 3)) * 255).astype(np.uint8)
    later = np.clip(bg * 1.03 + 4, 0, 255).astype(np.uint8)
    change = working_change(later, bg, (160, 120))
    assert np.abs(change).max() < 3 / 255
    with pytest.raises(DataError, match="background"):
        working_change(later[:50], bg, (160, 120))


@pytest.mark.parametrize("family,calibration", [("gelsight", "gelsight"),
                                                ("mini", "gelsight_mini")])
def test_held_out_real_ball_presses_reconstruct_their_contact(shipped, family, calibration):
    """The presses held out of the fit (every sixth): the contact radius within 20 % of the
    annotated one, the depth within 50 % of the sphere's (ball radius BALL_MM) and the
    deepest point on the touch."""
    rp = real_presses(calibration)
    lookup = shipped.lookup(family)
    s = lookup.work_size[0] / 640
    pixmm = optics(calibration).pixmm
    for i in range(0, len(rp["frames"]), HOLD_OUT_EVERY):
        hm = read_height(lookup, rp["frames"][i], rp["background"])
        r = float(rp["radii"][i])
        radius = np.sqrt((hm.height > hm.depth / 3).sum() / np.pi) / s
        assert abs(radius - r) < 0.2 * r
        r_mm = r * pixmm
        sphere = BALL_MM - np.sqrt(BALL_MM ** 2 - r_mm ** 2)
        assert abs(hm.depth - sphere) < 0.5 * sphere
        y, x = np.unravel_index(np.argmax(hm.height), hm.height.shape)
        assert np.hypot(x / s - rp["centres"][i][0], y / s - rp["centres"][i][1]) < r


def test_real_backgrounds_read_against_themselves_are_flat(shipped):
    for family, calibration in (("gelsight", "gelsight"), ("mini", "gelsight_mini")):
        bg = real_presses(calibration)["background"]
        lookup = shipped.lookup(family)
        assert read_height(lookup, bg, bg).depth < 1e-6
        assert not lookup.contact(bg, bg)[0]


def test_everyday_presses_stand_above_the_floors_that_blanks_stay_under(shipped):
    """Fresh renders (a seed the floors were not set on): broad, shallow presses of fabric and
    foam on the faint Mini read as contact; drifted blank pairs do not."""
    rng = np.random.default_rng(12345)
    lookup = shipped.lookup("mini")
    hits = [lookup.contact(p.frame, p.background)[0]
            for p in (render_press("mini", rng, kind) for kind in ("fabric", "foam")
                      for _ in range(4))]
    assert sum(hits) >= 7
    blanks = [lookup.contact(*render_blank_pair("mini", rng))[0] for _ in range(20)]
    assert sum(blanks) <= 1


def test_everyday_presses_meet_the_gelsights_domed_gel_and_balls_keep_its_apex(monkeypatch):
    """An everyday press is measured from the gel's rest surface (`on_gel`), a rigid ball from
    its apex (Taxim's calibration presses): the renders ask the optics so."""
    import ratouch.world.presses as presses

    asked = []
    real = presses.contact_change

    def spy(sensor, z, dome=None, on_gel=False):
        asked.append(on_gel)
        return real(sensor, z, dome, on_gel=on_gel)

    monkeypatch.setattr(presses, "contact_change", spy)
    rng = np.random.default_rng(7)
    render_press("gelsight", rng, "fabric")
    render_ball("gelsight", rng)
    assert asked == [True, False]


def test_gelsight_everyday_presses_stand_above_their_floors(shipped):
    """Broad, shallow presses on the domed GelSight (fabric, flat faces, foam) change the
    frame enough for the structured check against their background (fresh renders)."""
    rng = np.random.default_rng(54321)
    lookup = shipped.lookup("gelsight")
    hits = [lookup.contact(p.frame, p.background)[0]
            for p in (render_press("gelsight", rng, kind) for kind in ("fabric", "flat_face", "foam")
                      for _ in range(4))]
    assert sum(hits) >= 9, hits


def test_a_rendered_rigid_ball_is_taxims_ball_and_reads_as_one(shipped):
    """`render_ball` on the calibrated families: a hard press of the calibration's 2 mm ball,
    as deep as a cap whose contact radius is 0.5-0.95 of the ball's; read back through the
    shipped lookup it is contact, and on the Mini its depth is the cap's within 40 % (the
    GelSight's lookup, fitted on real frames, reads these renders shallower)."""
    from ratouch.world.sensors import family as family_row

    rng = np.random.default_rng(2024)
    lo = BALL_MM - np.sqrt(BALL_MM ** 2 - (0.5 * BALL_MM) ** 2)
    hi = BALL_MM - np.sqrt(BALL_MM ** 2 - (0.95 * BALL_MM) ** 2)
    for fam in ("gelsight", "mini"):
        for _ in range(3):
            p = render_ball(fam, rng)
            assert (p.kind, p.soft, p.family) == ("ball", False, fam)
            depth_mm = p.depth * family_row(fam).press_mm
            assert lo * 0.9 < depth_mm < hi * 1.1
            lookup = shipped.lookup(fam)
            assert lookup.contact(p.frame, p.background)[0]
            read = read_height(lookup, p.frame, p.background).depth
            assert 0 < read < 2.5
            if fam == "mini":
                assert abs(read - depth_mm) < 0.4 * depth_mm


def test_trust_reads_a_shallow_press_against_its_background(pipeline):
    """The trust block: a broad fabric press on a Mini with its (drifted) background is
    contact, with the structured score and the height map's numbers in the block."""
    rng = np.random.default_rng(7)
    p = render_press("mini", rng, "fabric")
    cal = pipeline.trust
    assert cal.geometry is not None
    state, _ = cal.contact_state(p.frame, p.background)
    assert state == "contact"
    enc = pipeline.encoders
    out = cal.assess(enc.encode_image([p.frame]), enc.encode_tactile([p.frame]), p.frame,
                     p.background)
    assert out["tactile"]["structure"]["contact"]
    assert out["tactile"]["geometry"]["units"] == "mm"
    assert out["tactile"]["firmness"]["reads"] in ("soft", "hard")
    assert 0 <= out["tactile"]["firmness"]["soft"] <= 1
    # a blank against its own background: no contact, so no firmness reading
    blank = cal.assess(enc.encode_image([p.frame]), enc.encode_tactile([p.background]),
                       p.background, p.background)
    assert blank["tactile"]["no_contact"] and blank["tactile"]["firmness"] is None


def test_an_unfamiliar_sensor_is_said_so_with_a_background(pipeline):
    """A frame unlike every family (a saturated magenta gel) read against its own background
    is flagged as unfamiliar, and the warning says the reading is a guess."""
    rng = np.random.default_rng(3)
    bg = np.zeros((128, 96, 3), np.uint8)
    bg[..., 0], bg[..., 2] = 230, 200
    bg = np.clip(bg + rng.integers(0, 6, bg.shape), 0, 255).astype(np.uint8)
    frame = bg.copy()
    frame[40:80, 30:60] = np.clip(frame[40:80, 30:60].astype(int) - 40, 0, 255)
    enc = pipeline.encoders
    out = pipeline.trust.assess(enc.encode_image([frame]), enc.encode_tactile([frame]), frame,
                                bg)
    assert out["tactile"]["unfamiliar_sensor"]
    assert any("looks like none of the sensors" in w for w in out["warnings"])


def test_a_recoloured_sensor_is_held_to_floors_of_its_own_against_its_background(pipeline):
    """docs/geometry.md, "A sensor unlike every rendered unit, read against its background":
    a blank pair recoloured alike beyond every rendered unit is read with the floors set for
    such a sensor (the block says so), the same pair as rendered with its family's. Where
    the structured change finds nothing and the with-background model (which reads the
    colours) says contact, the recoloured frame is "uncertain", and told why; the rendered
    unit's frame is "contact" as before."""
    cal = pipeline.trust
    assert all(lk.unfamiliar_floors for lk in cal.geometry.lookups.values())
    eager = dataclasses.replace(cal, contact_threshold_bg=-1e9)  # the model always says contact
    rng = np.random.default_rng(5)
    for _ in range(40):
        f, b = render_blank_pair("gelsight", rng)
        vf, vb = unfamiliar_pair_view(f, b, rng)
        if beyond_every_unit(vf) and not beyond_every_unit(f) and \
                background_change(vf, vb) >= cal.noise_floor:
            break
    else:
        pytest.fail("no recoloured blank pair beyond the limit in 40 draws")
    own, theirs = cal.structured_contact(f, b), cal.structured_contact(vf, vb)
    assert own["floors"] == "family" and theirs["floors"] == "unfamiliar sensor"
    assert theirs["threshold"] == round(cal.geometry.lookup(theirs["family"])
                                        .unfamiliar_threshold, 3)
    assert not theirs["contact"]
    assert eager.contact_state(vf, vb)[0] == "uncertain"
    if not own["contact"] and background_change(f, b) >= cal.noise_floor:
        assert eager.contact_state(f, b)[0] == "contact"
    enc = pipeline.encoders
    out = eager.assess(enc.encode_image([vf]), enc.encode_tactile([vf]), vf, vb)
    assert out["tactile"]["uncertain"] and out["tactile"]["unfamiliar_sensor"]
    assert any(w.startswith("contact uncertain: the tactile frame looks like none")
               for w in out["warnings"])


def test_a_lookups_floors_for_an_unfamiliar_sensor_round_trip_and_an_old_file_has_none(
        shipped, tmp_path):
    """The floors a sensor unlike every rendered unit is held to survive a save and decide
    `contact(..., unfamiliar=True)`; a lookup written before them loads with none, and such a
    frame is then held to the family's floors."""
    lk = shipped.lookup("mini").with_unfamiliar_floors((), float("inf"))
    family = (lk.structure_floors, lk.structure_threshold)
    stats = np.asarray(lk.structure_floors) * 1.5  # above the family's floors
    higher = lk.with_unfamiliar_floors(tuple(2 * f for f in lk.structure_floors), 1.2, on="x")
    assert higher.floors_for(False) == family and higher.floors_for(True)[1] == 1.2
    assert higher.contact(None, None, stats=stats)[0]
    assert not higher.contact(None, None, stats=stats, unfamiliar=True)[0]
    assert lk.contact(None, None, stats=stats, unfamiliar=True)[0]  # none: the family's
    path = GeometryCalibration({"mini": higher}).save(tmp_path / "a.json")
    again = GeometryCalibration.load(path).lookup("mini")
    assert again.floors_for(True) == (tuple(float(f"{2 * f:.6g}") for f in lk.structure_floors),
                                      1.2)
    assert again.meta["on"] == "x"
    body = json.loads(path.read_text())
    for key in ("unfamiliar_floors", "unfamiliar_threshold"):
        del body["lookups"]["mini"][key]
    (tmp_path / "old.json").write_text(json.dumps(body))
    old = GeometryCalibration.load(tmp_path / "old.json").lookup("mini")
    assert old.unfamiliar_floors == () and old.floors_for(True) == old.floors_for(False)


def test_firmness_from_shape_tells_soft_from_hard_on_fresh_renders(shipped):
    """docs/geometry.md, "Firmness read from shape": on renders of every kind of press from a
    stream the fit never draws from, each family's reading is right on both classes well
    above chance (balanced accuracy), and never collapses to one answer."""
    from ratouch.eval.presses import balanced_accuracy
    from ratouch.train.geometry import shape_renders

    for name, lookup in shipped.lookups.items():
        model = shipped.firmness[name]
        X, soft, _ = shape_renders(lookup, np.random.default_rng([4242, len(name)]), 6)
        said = [model.soft(x) >= 0.5 for x in X]
        acc = balanced_accuracy(said, list(soft))
        assert acc["balanced"] >= 0.7 and min(acc["soft_recall"], acc["hard_recall"]) >= 0.5, (
            name, acc)


def test_real_ball_presses_read_hard_from_their_shape(shipped):
    """Taxim's real presses of a rigid ball, read against their backgrounds (no real frame
    was fitted on): every one reads hard from its shape."""
    for family, calibration in (("gelsight", "gelsight"), ("mini", "gelsight_mini")):
        rp = real_presses(calibration)
        lookup = shipped.lookup(family)
        for frame in rp["frames"]:
            change = lookup.change(frame, rp["background"])
            hm = read_height(lookup, frame, rp["background"], change)
            assert shipped.read_firmness(family, hm, change)["reads"] == "hard"


def test_firmness_models_round_trip_and_an_old_file_still_loads(shipped, tmp_path):
    from ratouch.model.geometry import SHAPE_FEATURES

    again = GeometryCalibration.load(shipped.save(tmp_path / "g.json"))
    x = np.linspace(-1, 1, len(SHAPE_FEATURES))
    for name, model in shipped.firmness.items():
        assert again.firmness[name].soft(x) == pytest.approx(model.soft(x), abs=1e-5)
    body = json.loads((tmp_path / "g.json").read_text())
    # a calibration written before the firmness models: lookups, and no reading
    old = {k: v for k, v in body.items() if k != "firmness"}
    (tmp_path / "old.json").write_text(json.dumps(old))
    cal = GeometryCalibration.load(tmp_path / "old.json")
    assert cal.firmness == {} and cal.read_firmness("mini", None, None) is None  # type: ignore[arg-type]
    # a model that reads other features is not silently misread
    mini = body["firmness"]["mini"]
    mini.get("everyday", mini)["features"] = ["log depth"]  # a routed model's too
    (tmp_path / "other.json").write_text(json.dumps(body))
    with pytest.raises(DataError, match="other shape features"):
        GeometryCalibration.load(tmp_path / "other.json")


@pytest.mark.slow
def test_train_geometry_firmness_only_keeps_the_lookups(shipped, tmp_path, capsys):
    out = tmp_path / "lookups.json"
    shipped.save(out)
    assert main(["train", "geometry", "--firmness-only", "--firmness-per-kind", "2",
                 "--firmness-world", "24", "--out", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)["firmness"]
    assert set(report) == {"digit", "gelsight", "mini"}
    assert report["mini"]["renders"] == 14 and report["mini"]["world"]["renders"] == 24
    assert 0 < report["mini"]["soft_share"] < 1 and "router" in report["mini"]
    cal = GeometryCalibration.load(out)
    assert set(cal.firmness) == set(cal.lookups)
    assert (json.loads(out.read_text())["lookups"]
            == json.loads(shipped.save(tmp_path / "s.json").read_text())["lookups"])
    routed = cal.firmness["mini"]
    assert isinstance(routed, RoutedFirmness) and routed.everyday.meta["per_kind"] == 2
    assert "14 renders of everyday presses (2 a kind) and 24 of the world's renders" in \
        routed.meta["fitted_on"]
    assert set(routed.read(np.zeros(20))) == {"soft", "reads", "regime"}
    # too few world renders to hold both classes: refused, named, nothing written
    before = out.read_bytes()
    assert main(["train", "geometry", "--firmness-only", "--firmness-per-kind", "2",
                 "--firmness-world", "1", "--out", str(out)]) == 2
    assert "--firmness-world" in capsys.readouterr().err and out.read_bytes() == before


def test_a_drift_is_measured_once_and_read_back_the_same(tmp_path, monkeypatch):
    """`measure_drift` keeps its four figures in the cache folder, and a later process reads
    the same floats without measuring; a damaged file is measured again and rewritten; a cache
    that cannot be written is not an error."""
    from ratouch.world import presses

    measured = []
    real = presses._measured_drift

    def counted(calibration):
        measured.append(calibration)
        return real(calibration)

    monkeypatch.setattr(presses, "_measured_drift", counted)
    monkeypatch.setenv("RATOUCH_CACHE", str(tmp_path / "cache"))
    try:
        presses.measure_drift.cache_clear()
        first = presses.measure_drift("gelsight_mini")
        (kept,) = (tmp_path / "cache" / "drift").iterdir()
        assert json.loads(kept.read_text()) == dataclasses.asdict(first)
        presses.measure_drift.cache_clear()  # as a new process would
        assert presses.measure_drift("gelsight_mini") == first and measured == ["gelsight_mini"]
        kept.write_text("{")  # damaged: measured again, the same, and kept again
        presses.measure_drift.cache_clear()
        assert presses.measure_drift("gelsight_mini") == first and len(measured) == 2
        assert json.loads(kept.read_text()) == dataclasses.asdict(first)
        (tmp_path / "file").write_text("")  # a cache folder that cannot be made
        monkeypatch.setenv("RATOUCH_CACHE", str(tmp_path / "file"))
        presses.measure_drift.cache_clear()
        assert presses.measure_drift("gelsight_mini") == first and len(measured) == 3
    finally:
        presses.measure_drift.cache_clear()


def test_routed_firmness_mixes_its_regimes_by_the_router(tmp_path):
    """A routed firmness model reads a press by the everyday model where the router says
    everyday, by the world's where it says world, a mix between; it survives a save."""
    def logistic(bias, coef0=0.0):
        coef = np.zeros(20)
        coef[0] = coef0
        return FirmnessModel("mini", np.zeros(20), np.ones(20), coef, bias)

    x = np.zeros(20)
    hard, soft = logistic(-5.0), logistic(5.0)
    for router, want in ((logistic(-30.0), hard.soft(x)), (logistic(30.0), soft.soft(x)),
                         (logistic(0.0), 0.5 * (hard.soft(x) + soft.soft(x)))):
        m = RoutedFirmness("mini", hard, soft, router)
        assert m.soft(x) == pytest.approx(want)
    m = RoutedFirmness("mini", hard, soft, logistic(0.0, coef0=4.0), {"fitted_on": "test"})
    assert m.read(np.r_[1.0, np.zeros(19)])["regime"] == "world"
    low = m.read(np.r_[-1.0, np.zeros(19)])
    assert low["regime"] == "everyday" and low["reads"] == "hard"
    lookups = GeometryCalibration.load(geometry_calibration()).lookups
    out = GeometryCalibration(lookups, {}, {"mini": m}).save(tmp_path / "g.json")
    again = GeometryCalibration.load(out).firmness["mini"]
    assert isinstance(again, RoutedFirmness) and again.meta == {"fitted_on": "test"}
    for v in (np.r_[1.0, np.zeros(19)], np.r_[-1.0, np.zeros(19)], x):
        assert again.soft(v) == pytest.approx(m.soft(v), abs=1e-6)


def test_world_shape_renders_read_only_frames_with_contact_of_each_family(shipped):
    """The world's renders the firmness model also reads: the first of each family's units
    in the stream, with contact, labelled soft by the material's compliance."""
    from ratouch.train.geometry import world_shape_renders
    from ratouch.world.config import WorldConfig
    from ratouch.world.material import material
    from ratouch.world.sampler import World

    got = world_shape_renders(shipped.lookups, 3, start=0, split="test", stop=40)
    assert set(got) == {"digit", "gelsight", "mini"}
    world = World(WorldConfig())
    want: dict = {name: [] for name in got}
    for i in range(40):
        s = world.sample("test", i)
        if s.contact and len(want[s.family]) < 3:
            want[s.family].append(material(s.material).feel.compliance >= 0.5)
    for name, (X, y) in got.items():
        assert X.shape == (3, 20) and np.isfinite(X).all()
        assert list(y) == want[name]


def test_calibration_file_errors_are_clear(tmp_path):
    with pytest.raises(DataNotFoundError, match="ratouch train geometry"):
        GeometryCalibration.load(tmp_path / "none.json")
    (tmp_path / "bad.json").write_bytes(b"\xff\xfe not json")
    with pytest.raises(DataError, match="not a geometry calibration"):
        GeometryCalibration.load(tmp_path / "bad.json")


def test_shipped_calibration_round_trips(shipped, tmp_path):
    out = shipped.save(tmp_path / "g.json")
    again = GeometryCalibration.load(out)
    assert set(again.lookups) == set(shipped.lookups)
    frame, bg = render_blank_pair("digit", np.random.default_rng(0))
    for name, lookup in shipped.lookups.items():
        a = again.lookup(name)
        assert a.structure_threshold == pytest.approx(lookup.structure_threshold)
        ga = a.gradients(np.full((12, 16, 3), 0.02))[0]
        gb = lookup.gradients(np.full((12, 16, 3), 0.02))[0]
        np.testing.assert_allclose(ga, gb, atol=1e-4)


@pytest.mark.slow
def test_train_geometry_cli_writes_a_calibration(tmp_path, capsys):
    out = tmp_path / "lookups.json"
    assert main(["train", "geometry", "--samples", "3000", "--pairs", "20",
                 "--firmness-per-kind", "6", "--firmness-world", "24", "--out", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report["held_out"]) == {"digit", "gelsight", "mini"}
    cal = GeometryCalibration.load(out)
    assert all(np.isfinite(lk.structure_threshold) for lk in cal.lookups.values())
    assert all(len(lk.unfamiliar_floors) == 6 and np.isfinite(lk.unfamiliar_threshold)
               for lk in cal.lookups.values())


def test_train_geometry_unfamiliar_floors_sets_only_them(shipped, tmp_path, capsys):
    """`ratouch train geometry --unfamiliar-floors`: the stored lookups, their family floors
    and the firmness models are kept; only the floors for a sensor unlike every rendered unit
    are set (on --pairs recoloured blank pairs a family). Given with --firmness-only it is
    refused and nothing is written."""
    out = tmp_path / "lookups.json"
    shipped.save(out)
    assert main(["train", "geometry", "--unfamiliar-floors", "--pairs", "6",
                 "--out", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)["unfamiliar_floors"]
    assert set(report) == {"digit", "gelsight", "mini"}
    assert "(6 a family drawn)" in report["mini"]["floors_on"]
    cal, before = GeometryCalibration.load(out), shipped.save(tmp_path / "s.json")
    body, old = json.loads(out.read_text()), json.loads(before.read_text())
    assert body["firmness"] == old["firmness"]
    for name, lk in cal.lookups.items():
        was = shipped.lookup(name)
        assert lk.floors_for(False) == was.floors_for(False)  # as loaded: the same floats
        assert len(lk.unfamiliar_floors) == 6 and np.isfinite(lk.unfamiliar_threshold)
        assert body["lookups"][name]["weights"] == old["lookups"][name]["weights"]
    written = out.read_bytes()
    assert main(["train", "geometry", "--unfamiliar-floors", "--firmness-only",
                 "--out", str(out)]) == 2
    assert "give one of them" in capsys.readouterr().err and out.read_bytes() == written


def test_eval_presses_cli(capsys):
    assert main(["eval", "presses", "--n", "1", "--blanks", "2", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert set(rep) == {"digit", "gelsight", "mini"}
    assert set(rep["mini"]["kinds"]) >= {"fabric", "foam", "edge"}
    shape = rep["mini"]["shape_firmness"]
    assert shape["n"] == 7 and 0 <= shape["balanced"] <= 1


def test_eval_presses_landscape_renders_every_pair_landscape(capsys, monkeypatch):
    """`ratouch eval presses --landscape`: every press, blank pair and cross-unit pair is
    rendered 96 x 128 (portrait, 128 x 96, without it), and the report is the same shape."""
    import ratouch.eval.presses as presses_mod
    import ratouch.world.presses as world_presses

    seen: list = []

    def spy(fn):
        def wrapped(*a, **k):
            out = fn(*a, **k)
            seen.append((out.frame if hasattr(out, "frame") else out[0]).shape[:2])
            return out
        return wrapped

    for mod in (presses_mod, world_presses):
        for name in ("render_press", "render_blank_pair", "render_cross_unit_pair"):
            if hasattr(mod, name):
                monkeypatch.setattr(mod, name, spy(getattr(mod, name)))
    for flag, hw in (([], (128, 96)), (["--landscape"], (96, 128))):
        seen.clear()
        assert main(["eval", "presses", "--n", "1", "--blanks", "1", "--cross-unit", "1",
                     "--json", *flag]) == 0
        rep = json.loads(capsys.readouterr().out)
        assert set(rep["cross_unit"]) == {"digit", "gelsight", "mini"}
        assert rep["gelsight"]["n_blanks"] == 1
        assert len(seen) == 3 * (7 + 1 + 1) and set(seen) == {hw}, (flag, set(seen))


def test_eval_presses_world_reads_the_worlds_own_frames_both_ways(capsys):
    """`ratouch eval presses --world N`: the world's first N test presses and the same samples
    without contact, read alone and against their background, counted per contact state and
    family (the counts add up to the frames read; its test presses are contact against their
    background and its blanks are not)."""
    assert main(["eval", "presses", "--n", "1", "--blanks", "1", "--world", "6", "--json"]) == 0
    world = json.loads(capsys.readouterr().out)["world"]
    assert set(world) <= {"digit", "gelsight", "mini", "all"} and "all" in world
    for kind in ("presses", "blanks"):
        for way in ("alone", "with_background"):
            counts = world["all"][kind][way]
            assert set(counts) == {"contact", "uncertain", "no contact"}
            assert sum(counts.values()) == 6
            assert sum(world[f][kind][way]["contact"] for f in world if f != "all") \
                == counts["contact"]
    assert world["all"]["presses"]["with_background"]["contact"] >= 5
    assert world["all"]["blanks"]["alone"]["contact"] == 0
    if "gelsight" in world:
        assert world["gelsight"]["blanks"]["with_background"]["contact"] == 0
    assert main(["eval", "presses", "--n", "1", "--blanks", "1", "--world", "3"]) == 0
    assert "world test blanks | alone" in capsys.readouterr().out


def test_the_worlds_blank_frames_against_their_background_are_not_contact(pipeline):
    """The world's renders are noisier than the drifted blank pairs the structured check's
    floors are set on (its DIGIT frames 2-5 times): read against their own noise, its
    no-contact frames against their unit's background are not contact (243 of 402 were,
    before), and its presses still are."""
    from ratouch.eval.presses import world_contact

    world = world_contact(pipeline.trust, n=12)
    assert world["all"]["blanks"]["with_background"]["contact"] == 0
    assert world["all"]["presses"]["with_background"]["contact"] == 12


@pytest.mark.slow
def test_eval_presses_probe_cli(capsys):
    """`ratouch eval presses --probe N`: per family, linear probes of the material and of
    soft against hard from the embedding (with and without the background), the shape and
    both, as a table and as JSON."""
    assert main(["eval", "presses", "--n", "1", "--blanks", "1", "--probe", "2"]) == 0
    table = capsys.readouterr().out
    for said in ("| digit | embedding with background |", "| mini | shape |",
                 "| gelsight | embedding and shape |"):
        assert said in table, said
    assert main(["eval", "presses", "--n", "1", "--blanks", "1", "--probe", "2",
                 "--json"]) == 0
    probe = json.loads(capsys.readouterr().out)["probe"]
    assert set(probe) == {"digit", "gelsight", "mini"}
    for row in probe.values():
        assert row["presses"] == 14 and 0 < row["material_chance"] < 1
        for key in ("embedding_with_background", "embedding_alone", "shape",
                    "embedding_and_shape"):
            assert 0 <= row[key]["material"] <= 1 and 0 <= row[key]["firmness"] <= 1


class _ReadsSoftWithBackground:
    """A stand-in pipeline: "soft, plush" where a background is given, no contact without."""

    def __init__(self):
        self.queries = 0

    def query(self, visual, tactile, box, k, background=None):
        self.queries += 1
        state = "contact" if background is not None else "no contact"
        return {"trust": {"tactile": {"state": state, "contact": 1.0,
                                      "sensor": {"family": "mini"}}},
                "neighbours": {"tactile": [{"caption": "soft, plush"}],
                               "adapted": [{"caption": "hard, rigid"}]},
                "description": {"ra_touch": "soft"}, "warnings": []}


def test_press_readings_count_firmness_refusals_and_the_judge():
    """`eval presses --readings`: hard presses read "soft" count as hard-read-soft, a refused
    press has no firmness and scores as an empty answer, and every family and kind is read
    with and without its background."""
    from ratouch.eval.judge import OfflineJudge
    from ratouch.eval.presses import material_label, press_readings
    from ratouch.world.presses import PRESS_KINDS

    pipe = _ReadsSoftWithBackground()
    rep = press_readings(pipe, OfflineJudge(), n=1, seed=0)
    assert set(rep) == {"digit", "gelsight", "mini"}
    assert pipe.queries == 3 * 2 * len(PRESS_KINDS)
    for fam in rep.values():
        bg, alone = fam["with_background"], fam["without_background"]
        assert bg["presses"] == len(PRESS_KINDS) == bg["hard"] + bg["soft"]
        assert bg["soft"] >= 2  # fabric and foam at least
        assert bg["refused"] == 0 and bg["hard_read_soft"] == bg["hard"]
        assert bg["soft_read_hard"] == 0 and bg["distinct_readings"] == 1
        assert bg["firmness_right"] == round(bg["soft"] / bg["presses"], 4)
        assert alone["refused"] == alone["presses"] and alone["hard_read_soft"] == 0
        assert alone["firmness_right"] == 0 and alone["distinct_readings"] == 0
        assert bg["judge"] > alone["judge"]  # an empty answer scores lowest
        # the adapted tactile query's reading, counted the same way
        ad = bg["adapted"]
        assert ad["presses"] == bg["presses"] and ad["hard_read_soft"] == 0
        assert ad["soft_read_hard"] == ad["soft"] == bg["soft"] and ad["distinct_readings"] == 1
        assert alone["adapted"]["refused"] == alone["presses"]
        # no firmness router read these presses: the reading is the paper's tactile query's
        assert bg["routed_to_adapted"] == 0 and bg["tactile"]["judge"] == bg["judge"]
    assert material_label("terry_cloth").count(",") == 4


class _EverydayWithBackground(_ReadsSoftWithBackground):
    """The stand-in, with a firmness router that reads every press against a background as
    an everyday one."""

    def query(self, visual, tactile, box, k, background=None):
        out = super().query(visual, tactile, box, k, background)
        out["trust"]["tactile"].update(background=background is not None, firmness={
            "soft": 0.2, "reads": "hard", "regime": "everyday"})
        return out


def test_press_readings_are_routed_by_the_press_regime():
    """An everyday press read against its background is read by the adapted query (the
    paper's tactile reading beside it); without the background, by the paper's."""
    from ratouch.eval.judge import OfflineJudge
    from ratouch.eval.presses import press_readings

    rep = press_readings(_EverydayWithBackground(), OfflineJudge(), n=1, seed=0)
    for fam in rep.values():
        bg, alone = fam["with_background"], fam["without_background"]
        assert bg["routed_to_adapted"] == 1.0 and alone["routed_to_adapted"] == 0.0
        # the routed reading is the adapted one ("hard, rigid"): no hard press reads soft
        assert bg["hard_read_soft"] == 0 and bg["soft_read_hard"] == bg["soft"]
        assert bg["tactile"]["hard_read_soft"] == bg["hard"]  # "soft, plush"
        assert bg["judge"] == bg["adapted"]["judge"] != bg["tactile"]["judge"]


def test_eval_presses_readings_cli(monkeypatch, capsys):
    """`ratouch eval presses --readings N` reads through the pipeline it loads and prints the
    readings table (and the JSON's "readings")."""
    from ratouch.cli import eval as cli_eval

    monkeypatch.setattr(cli_eval.RATouchPipeline, "load",
                        classmethod(lambda cls, *a, **kw: _ReadsSoftWithBackground()))
    assert main(["eval", "presses", "--n", "1", "--blanks", "1", "--readings", "1"]) == 0
    out = capsys.readouterr().out
    assert "| family | background | reading | refused | hard read soft |" in out
    assert "| mini | without | tactile | 7/7 |" in out and "| mini | with | adapted | 0/7 |" in out
    assert main(["eval", "presses", "--n", "1", "--blanks", "1", "--readings", "1",
                 "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["readings"]["gelsight"]["with_background"]["refused"] == 0


def test_a_lookup_reads_any_working_size_the_same_as_a_fresh_one(shipped):
    """The perceptron's output at zero change is kept per working size: a lookup that has
    read one size reads another (and the first again) exactly as a fresh copy of it does."""
    from ratouch.model.geometry import GradientLookup

    lookup = shipped.lookup("gelsight")
    rng = np.random.default_rng(3)
    changes = [rng.normal(0, 0.02, (120, 160, 3)), rng.normal(0, 0.02, (160, 120, 3))]
    for c in changes + changes[:1]:
        fresh = GradientLookup.from_dict(lookup.to_dict())
        for mine, theirs in zip(lookup.gradients(c), fresh.gradients(c)):
            assert np.array_equal(mine, theirs)
    assert set(lookup._at_rest) >= {(120, 160), (160, 120)}
    assert not lookup.with_floors((1.0,) * 6, 2.0)._at_rest  # a new lookup starts empty


def test_the_lookups_perceptron_is_the_plain_one_pixel_by_pixel(shipped):
    """The perceptron reads pixels as columns, some at a time: it computes what the plain
    perceptron (a pixel a row, all at once) does, for a pixel count that is not a multiple of
    the chunk, and its gradients are of the frame's shape."""
    from ratouch.model import geometry

    lookup = shipped.lookup("mini")
    rng = np.random.default_rng(5)
    x = rng.normal(0, 1, (5, 2 * geometry._COLUMNS + 37))
    plain = x.T
    for n, (wt, b) in enumerate(zip(lookup.weights, lookup.biases)):
        plain = plain @ wt + b
        if n < len(lookup.weights) - 1:
            plain = np.maximum(plain, 0)
    got = lookup._forward(x)
    assert got.shape == (2, x.shape[1])
    np.testing.assert_allclose(got, plain.T, rtol=1e-12, atol=1e-12)
    gx, gy = lookup.gradients(rng.normal(0, 0.02, (31, 43, 3)))
    assert gx.shape == gy.shape == (31, 43)
    assert np.array_equal(lookup.gradients(np.zeros((31, 43, 3)))[0], np.zeros((31, 43)))


def test_a_pairs_noise_is_read_from_its_finest_change_and_lifts_its_floors(shipped, tmp_path):
    """`pair_noise` grows with the camera noise a pair carries and barely with a smooth press;
    a pair noisier than the blanks a family's floors were set on (`noise_ref`) has its
    structured score divided by how much noisier it is, a quieter one is read as is; a lookup
    written before `noise_ref` loads without it and reads every pair as is."""
    from ratouch.model.geometry import drift_free_change, noise_adjusted, pair_noise

    rng = np.random.default_rng(3)
    frame, bg = render_blank_pair("mini", rng)
    lk = shipped.lookup("mini")
    quiet = pair_noise(drift_free_change(frame, bg, lk.work_size, turn=True))
    noisy = np.clip(frame + rng.normal(0, 6, frame.shape), 0, 255).astype(np.uint8)
    loud = pair_noise(drift_free_change(noisy, bg, lk.work_size, turn=True))
    assert loud > 2 * quiet
    assert noise_adjusted(3.0, 2.0, 1.0) == 1.5 and noise_adjusted(3.0, 0.5, 1.0) == 3.0
    assert noise_adjusted(3.0, None, 1.0) == 3.0 and noise_adjusted(3.0, 2.0, None) == 3.0
    assert lk.noise_ref is not None and 0.2 * quiet < lk.noise_ref < 5 * quiet
    # the same pair, its score against the family's floors with and without its noise read
    plain = dataclasses.replace(lk, noise_ref=None)
    _, s_read = lk.contact(noisy, bg)
    _, s_plain = plain.contact(noisy, bg)
    ratio = lk.change_and_noise(noisy, bg)[1] / lk.noise_ref
    assert ratio > 1 and s_read == pytest.approx(s_plain / ratio)
    # statistics given alone are read as they are
    stats = np.asarray(lk.structure_floors) * 1.5
    assert lk.contact(None, None, stats=stats) == plain.contact(None, None, stats=stats)
    path = GeometryCalibration({"mini": lk}).save(tmp_path / "a.json")
    assert GeometryCalibration.load(path).lookup("mini").noise_ref == pytest.approx(
        lk.noise_ref, rel=1e-5)
    body = json.loads(path.read_text())
    del body["lookups"]["mini"]["noise_ref"]
    (tmp_path / "old.json").write_text(json.dumps(body))
    assert GeometryCalibration.load(tmp_path / "old.json").lookup("mini").noise_ref is None


def test_train_geometry_floors_only_sets_the_family_floors_and_their_noise(shipped, tmp_path,
                                                                           capsys):
    """`ratouch train geometry --floors-only`: each family's floors, threshold and noise are
    set on --pairs drifted blank pairs; the lookups' weights, the floors for an unfamiliar
    sensor and the firmness models are kept. With another part's flag it is refused and
    nothing is written."""
    out = tmp_path / "lookups.json"
    shipped.save(out)
    assert main(["train", "geometry", "--floors-only", "--pairs", "8", "--out", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)["floors"]
    assert set(report) == {"digit", "gelsight", "mini"}
    assert all(r["noise_ref"] > 0 and np.isfinite(r["threshold"]) for r in report.values())
    # the DIGIT's second reading (a lighting field removed) gets floors of its own, kept
    assert report["digit"]["field_noise_ref"] > 0 and np.isfinite(report["digit"]["field_threshold"])
    assert "field_threshold" not in report["gelsight"] and "field_threshold" not in report["mini"]
    cal, before = GeometryCalibration.load(out), shipped.save(tmp_path / "s.json")
    digit = cal.lookup("digit")
    assert len(digit.field_floors) == 6 and digit.field_threshold == pytest.approx(
        report["digit"]["field_threshold"])
    assert not cal.lookup("mini").field_floors
    body, old = json.loads(out.read_text()), json.loads(before.read_text())
    assert body["firmness"] == old["firmness"]
    for name, lk in cal.lookups.items():
        assert lk.floors_for(True) == shipped.lookup(name).floors_for(True)
        assert body["lookups"][name]["weights"] == old["lookups"][name]["weights"]
        assert "8 drifted blank render pairs" in lk.meta["floors_on"]
    written = out.read_bytes()
    assert main(["train", "geometry", "--floors-only", "--firmness-only",
                 "--out", str(out)]) == 2
    assert "give one of them" in capsys.readouterr().err and out.read_bytes() == written


def test_a_blank_against_another_units_background_is_counted_per_state(capsys):
    """`render_cross_unit_pair` draws two units of one family; `ratouch eval presses
    --cross-unit N` reads N such blanks a family and counts each contact state and the
    structured check's calls (the counts add up to N)."""
    from ratouch.world.presses import render_cross_unit_pair

    a, b = render_cross_unit_pair("mini", np.random.default_rng(1))
    assert a.shape == b.shape == (128, 96, 3) and a.dtype == np.uint8
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 0
    assert main(["eval", "presses", "--n", "1", "--blanks", "1", "--cross-unit", "3",
                 "--json"]) == 0
    cross = json.loads(capsys.readouterr().out)["cross_unit"]
    assert set(cross) == {"digit", "gelsight", "mini"}
    for r in cross.values():
        assert r["pairs"] == 3 and r["contact"] + r["uncertain"] + r["no contact"] == 3
        assert 0 <= r["structured_contact"] <= 3
    assert main(["eval", "presses", "--n", "1", "--blanks", "1", "--cross-unit", "2"]) == 0
    assert "blank against another unit's background" in capsys.readouterr().out


def _gelsight_units():
    from ratouch.world.sensors import family_sensors, has_markers

    units = list(family_sensors("gelsight"))
    return [s for s in units if has_markers(s)], [s for s in units if not has_markers(s)]


def test_a_backgrounds_marker_dots_are_found_in_its_own_units_frames_only():
    """`background_markers`: a GelSight unit's marker grid is found in its own drifted blanks
    and presses (share 1), not in a blank of another unit (with its own grid, or none); a
    background without markers is not read (None); sizes must agree."""
    from ratouch.model.markers import MIN_DOTS, background_markers, marker_dots
    from ratouch.world.presses import drifted, family_drift, to_uint8
    from ratouch.world.tactile import sensor_background

    marked, plain = _gelsight_units()
    assert len(marked) >= 2 and plain
    rng = np.random.default_rng(6)
    drift = family_drift("gelsight")
    shot = lambda s: to_uint8(drifted(sensor_background(s, (128, 96)).astype(np.float64),  # noqa: E731
                                      drift, rng))
    bg = shot(marked[0])
    assert len(marker_dots(bg)) >= MIN_DOTS and len(marker_dots(shot(plain[0]))) < MIN_DOTS
    own = background_markers(shot(marked[0]), bg)
    assert own is not None and own["share"] == 1.0 and not own["moved"]
    for other in (marked[1], plain[0]):
        cross = background_markers(shot(other), bg)
        assert cross is not None and cross["moved"] and cross["share"] < 0.3
    # a frame with a grid of its own against a background without one: the frame's grid
    # is read (markers are printed on the gel: another unit's background)
    grid = background_markers(shot(marked[0]), shot(plain[0]))
    assert grid is not None and grid["moved"] and grid["share"] is None
    assert grid["lattice"]["dots"] >= 40 and 10 <= grid["lattice"]["pitch"] <= 12
    assert background_markers(shot(plain[1] if len(plain) > 1 else plain[0]),
                              shot(plain[0])) is None
    with pytest.raises(DataError, match="background"):
        background_markers(bg[:64], bg)


def test_another_units_grid_a_pixel_away_is_told_by_the_found_dots_shift(pipeline):
    """Two GelSight units whose marker grids lie a pixel apart: more than half of one's dots
    are found in the other's blank, but the found dots sit off as a whole (`shift` at least
    `MAX_SHIFT`), so the pair is "moved" and the frame "uncertain", with a warning saying so;
    the unit's own blank and its presses shift by 0."""
    from ratouch.model.markers import MAX_SHIFT, MIN_FOUND, background_markers
    from ratouch.world.presses import drifted, family_drift, render_press, to_uint8
    from ratouch.world.tactile import sensor_background

    marked, _ = _gelsight_units()
    rng = np.random.default_rng(12)
    drift = family_drift("gelsight")
    shot = lambda s: to_uint8(drifted(sensor_background(s, (128, 96)).astype(np.float64),  # noqa: E731
                                      drift, rng))
    near = []
    for a in marked:
        for b in marked:
            m = background_markers(shot(a), shot(b))
            assert m is not None and m["moved"] == (a != b), (a, b, m)
            if a == b:
                assert m["shift"] == 0.0
            elif m["share"] >= MIN_FOUND:
                near.append((a, b))
                assert m["shift"] >= MAX_SHIFT
    assert near  # the renders hold such a pair (units 9 and 10: a pixel apart)
    a, b = near[0]
    frame, other = shot(a), shot(b)
    trust, enc = pipeline.trust, pipeline.encoders
    assert trust.contact_state(frame, other)[0] == "uncertain"
    out = trust.assess(enc.encode_image([frame]), enc.encode_tactile([frame]), frame, other)
    assert out["tactile"]["state"] == "uncertain" and out["tactile"]["markers"]["moved"]
    assert any("px off as a whole" in w for w in out["warnings"])
    read = 0
    for kind in ("flat_face", "fabric", "small_curved"):  # a press moves only its contact's
        for _ in range(4):
            p = render_press("gelsight", rng, kind=kind)
            m = background_markers(p.frame, p.background)
            if m is not None:  # None: a unit without markers
                read += 1
                assert m["shift"] == 0.0 and not m["moved"], kind
    assert read  # some of the presses were on a unit with markers


def test_a_marker_grid_is_told_from_a_textures_dots():
    """`marker_lattice`: every GelSight unit's marker grid (its blank, portrait at 128 x 96
    and 640 x 480, landscape at 96 x 128 and 480 x 640) is a grid spanning at least
    `LATTICE_SPAN` pitches; no everyday press of a unit without markers is (every kind and
    family, their textures' dots included), nor a frame with too few dots."""
    from ratouch.model.markers import LATTICE_SPAN, marker_lattice
    from ratouch.world.presses import PRESS_KINDS, render_press
    from ratouch.world.sensors import family_names
    from ratouch.world.tactile import sensor_background

    marked, _ = _gelsight_units()
    for hw in ((128, 96), (640, 480), (96, 128), (480, 640)):
        for unit in marked:
            blank = (sensor_background(unit, hw) * 255 + 0.5).astype(np.uint8)
            grid = marker_lattice(blank)
            assert grid is not None and grid["cv"] <= 0.10, (hw, unit)
            assert grid["cover"] >= LATTICE_SPAN, (hw, unit)
    rng = np.random.default_rng(29)
    read = 0
    for fam in family_names():
        for kind in PRESS_KINDS:
            for hw in ((128, 96), (96, 128), (128, 96)):
                p = render_press(fam, rng, kind, hw)
                if fam == "gelsight" and marker_lattice(p.background) is not None:
                    continue  # a unit with markers: its grid is its own
                assert marker_lattice(p.frame) is None, (fam, kind, hw)
                read += 1
    assert read >= 40
    assert marker_lattice(np.full((128, 96, 3), 128, np.uint8)) is None


def test_a_frame_against_another_units_marker_grid_is_uncertain_and_said_so(pipeline):
    """Read against a background whose marker dots the frame does not show, a GelSight blank
    is "uncertain" (not "contact"), the trust block carries the reading and the warning says
    to give this unit's background; against its own background the same frame is "no
    contact", and a press on a unit with markers is read as without the check."""
    from ratouch.world.presses import drifted, family_drift, render_press, to_uint8
    from ratouch.world.tactile import sensor_background

    marked, _ = _gelsight_units()
    rng = np.random.default_rng(8)
    drift = family_drift("gelsight")
    shot = lambda s: to_uint8(drifted(sensor_background(s, (128, 96)).astype(np.float64),  # noqa: E731
                                      drift, rng))
    frame, own, other = shot(marked[0]), shot(marked[0]), shot(marked[1])
    trust = pipeline.trust
    assert trust.contact_state(frame, other)[0] == "uncertain"
    assert trust.contact_state(frame, own)[0] == "no contact"
    enc = pipeline.encoders
    out = trust.assess(enc.encode_image([frame]), enc.encode_tactile([frame]), frame, other)
    assert out["tactile"]["state"] == "uncertain" and out["tactile"]["markers"]["moved"]
    assert any("marker dots are not where this frame's are" in w for w in out["warnings"])
    # the frame's own grid against a background without one: uncertain, said so
    _, plain = _gelsight_units()
    bare = shot(plain[0])
    out = trust.assess(enc.encode_image([frame]), enc.encode_tactile([frame]), frame, bare)
    assert out["tactile"]["state"] == "uncertain" and out["tactile"]["markers"]["lattice"]
    assert any("the frame shows a grid of" in w and "that the background lacks" in w
               for w in out["warnings"])
    from ratouch.model.markers import background_markers

    read = 0
    for _ in range(24):                      # presses on units with markers
        p = render_press("gelsight", rng, kind="small_curved")
        marks = background_markers(p.frame, p.background)
        if marks is not None:
            # the dots are found, so the frame is read as it was without them
            assert not marks["moved"] and trust.contact_state(p.frame, p.background) == \
                trust.contact_state(p.frame, p.background, markers=None)
            read += 1
    assert read >= 3


def test_a_smooth_lighting_field_is_removed_by_the_field_fit_only():
    """`drift_free_change(field=True)` undoes a gain and an offset that are each a quadratic
    in the position (a unit whose LEDs glow elsewhere); the plain gain-and-offset fit does
    not, and a local press survives the field fit."""
    from ratouch.model.geometry import drift_free_change

    rng = np.random.default_rng(3)
    bg = rng.uniform(60, 200, (96, 128, 3))
    v, u = np.meshgrid(np.linspace(-1, 1, 96), np.linspace(-1, 1, 128), indexing="ij")
    gain = (1 + 0.15 * u - 0.1 * v * v)[..., None]
    frame = np.clip(bg * gain + 20 * u[..., None] * v[..., None], 0, 255)
    to8 = lambda a: np.round(a).astype(np.uint8)  # noqa: E731
    size = (128, 96)
    plain = np.abs(drift_free_change(to8(frame), to8(bg), size)).mean()
    field = np.abs(drift_free_change(to8(frame), to8(bg), size, field=True)).mean()
    assert field < 0.2 * plain and field < 0.004
    pressed = frame.copy()
    pressed[40:56, 60:76] += 40
    change = drift_free_change(to8(pressed), to8(bg), size, field=True)
    assert np.abs(change[40:56, 60:76]).mean() > 20 * np.abs(change[:20, :20]).mean()


def test_a_mini_blank_just_over_the_structured_floor_is_uncertain_and_said_so(pipeline):
    """A Mini blank read against another Mini unit's background whose structured change is
    barely above the threshold (within `BAND_FACTOR` x it) is "uncertain", never "contact";
    the structure block carries `band` and the warning says the change is barely above a
    blank's. A firm press stands far above the band and stays "contact"; the other families'
    blocks carry no band."""
    from ratouch.model.geometry import BAND_FACTOR
    from ratouch.world.presses import render_cross_unit_pair, render_press

    trust = pipeline.trust
    rng = np.random.default_rng(12)
    inside = 0
    for _ in range(60):
        frame, bg = render_cross_unit_pair("mini", rng)
        block = trust.read_geometry(frame, bg, height=False)["structure"]
        state = trust.contact_state(frame, bg, structured=block)[0]
        band = block.get("band")
        assert (band is not None) == bool(block["contact"])
        if band is None:
            continue
        assert band["top"] == pytest.approx(BAND_FACTOR * block["threshold"], abs=2e-3)
        assert band["inside"] == (block["score"] <= band["top"])
        assert state == ("uncertain" if band["inside"] else "contact")
        if band["inside"]:
            inside += 1
            enc = pipeline.encoders
            out = trust.assess(enc.encode_image([frame]), enc.encode_tactile([frame]), frame,
                               bg)
            assert out["tactile"]["state"] == "uncertain"
            assert any("barely above what a blank frame shows" in w
                       and "give this unit's background" in w for w in out["warnings"])
    assert inside >= 1
    for _ in range(4):
        p = render_press("mini", rng, kind="small_curved")
        block = trust.read_geometry(p.frame, p.background, height=False)["structure"]
        assert block["band"] == {"top": block["band"]["top"], "inside": False}
        assert trust.contact_state(p.frame, p.background)[0] == "contact"
    for fam in ("digit", "gelsight"):   # only the Mini reads the band
        p = render_press(fam, rng, kind="small_curved")
        assert "band" not in trust.read_geometry(p.frame, p.background, height=False,
                                                 family=fam)["structure"]


def test_a_digit_blank_against_another_units_lighting_is_uncertain_and_said_so(pipeline):
    """A DIGIT blank read against another DIGIT unit's background, whose structured change a
    smooth lighting field alone explains, is "uncertain" (read, with a caveat), never
    "contact"; the structure block carries `lighting_field` and the warning says to give this
    unit's background. Against its own unit's background the field is not consulted for a
    blank (the structured check finds nothing) and a firm press stays "contact"."""
    from ratouch.world.presses import render_cross_unit_pair, render_press

    trust = pipeline.trust
    rng = np.random.default_rng(12)
    explained = 0
    for _ in range(12):
        frame, bg = render_cross_unit_pair("digit", rng)
        block = trust.read_geometry(frame, bg, height=False)["structure"]
        state = trust.contact_state(frame, bg, structured=block)[0]
        field = block.get("lighting_field")
        assert (field is not None) == bool(block["contact"])
        if field and field["explains"]:
            explained += 1
            assert state == "uncertain"
            enc = pipeline.encoders
            out = trust.assess(enc.encode_image([frame]), enc.encode_tactile([frame]), frame,
                               bg)
            assert out["tactile"]["state"] == "uncertain"
            assert out["tactile"]["structure"]["lighting_field"]["explains"]
            assert any("smooth lighting field" in w and "give this unit's background" in w
                       for w in out["warnings"])
    assert explained >= 4
    for _ in range(6):
        p = render_press("digit", rng, kind="small_curved")
        assert trust.contact_state(p.frame, p.background)[0] == "contact"
    for fam in ("gelsight", "mini"):   # only the DIGIT's lookup reads the field
        frame, bg = render_cross_unit_pair(fam, rng)
        read = trust.read_geometry(frame, bg, height=False, family=fam)
        assert "lighting_field" not in read["structure"]
