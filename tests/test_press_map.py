"""The press map (`ratouch.model.press_map`): the adapted tactile query brings everyday
presses back to their material's captions; its file, its mode, its fit and its CLI."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from ratouch.cli import main
from ratouch.errors import DataError, DataNotFoundError
from ratouch.model.press_map import PressMap
from ratouch.paths import press_map
from ratouch.search.modes import QUERY_MODES
from ratouch.train.press_map import (
    PressMapConfig,
    everyday_presses,
    fit_press_map,
    material_index,
    precision_at5,
)


@pytest.fixture(scope="module")
def shipped_map():
    return PressMap.load(press_map("default-s"))


def test_the_map_is_a_residual_on_unit_vectors_and_round_trips(shipped_map, tmp_path):
    rng = np.random.default_rng(0)
    T = rng.normal(size=(5, shipped_map.dim)).astype(np.float32)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    out = shipped_map.apply(T)
    assert out.shape == T.shape and out.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1, atol=1e-5)
    zero = PressMap(shipped_map.w1, shipped_map.b1, shipped_map.w2 * 0, shipped_map.b2 * 0)
    np.testing.assert_allclose(zero.apply(T), T, atol=1e-6)  # no residual: the identity
    again = PressMap.load(shipped_map.save(tmp_path / "m.npz"))
    np.testing.assert_allclose(again.apply(T), out, atol=1e-6)
    assert again.meta["encoder"] == "default-s"
    with pytest.raises(DataError, match=r"\(N, 384\)"):
        shipped_map.apply(T[:, :10])


def test_the_regime_router_reads_embeddings_and_round_trips(shipped_map, tmp_path):
    """The map's router (which regime a frame read alone is a press of): a probability per
    embedding, named at 0.5; saved with the map; a map without one loads without one; a
    router of another width is refused."""
    router = shipped_map.router
    assert router is not None and router.coef.shape == (shipped_map.dim,)
    rng = np.random.default_rng(1)
    T = rng.normal(size=(4, shipped_map.dim))
    p = router.everyday(T)
    assert p.shape == (4,) and ((0 <= p) & (p <= 1)).all()
    read = router.read(T)
    assert [r["regime"] for r in read] == ["everyday" if x >= 0.5 else "world" for x in p]
    again = PressMap.load(shipped_map.save(tmp_path / "m.npz"))
    assert again.router is not None
    np.testing.assert_array_equal(again.router.everyday(T), p)
    bare = PressMap(shipped_map.w1, shipped_map.b1, shipped_map.w2, shipped_map.b2)
    assert PressMap.load(bare.save(tmp_path / "bare.npz")).router is None
    narrow = dataclasses.replace(router, coef=router.coef[:10])
    with pytest.raises(DataError, match="its router reads"):
        PressMap.load(dataclasses.replace(shipped_map, router=narrow).save(tmp_path / "n.npz"))


def test_a_frame_alone_carries_the_routers_reading(pipeline):
    """The trust block of a frame read without a background holds the press map's regime
    reading (the touch-only reading follows it); with a background it does not (the shape
    decides there)."""
    from ratouch.world.sampler import World

    s = World().sample("test", 3)
    alone = pipeline.query(s.visual, s.tactile, k=3)
    regime = alone["trust"]["tactile"]["press_regime"]
    assert regime["regime"] in ("everyday", "world") and 0 <= regime["everyday"] <= 1
    bg = pipeline.query(s.visual, s.tactile, k=3,
                        background=World().background_image(s.sensor))
    assert "press_regime" not in bg["trust"]["tactile"]


def test_bad_files_are_clear(tmp_path):
    with pytest.raises(DataNotFoundError, match="ratouch train press-map"):
        PressMap.load(tmp_path / "none.npz")
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(DataError, match="not a press map"):
        PressMap.load(tmp_path / "bad.npz")


def test_the_adapted_mode_reads_the_map_and_falls_back_to_the_tactile_query(pipeline):
    """On the tests' pipeline (the shipped map): the adapted mode's query is the map of the
    tactile embedding; without a map it is the tactile embedding itself."""
    assert pipeline.press_map is not None
    T = pipeline.encoders.encode_tactile([np.full((128, 96, 3), 120, np.uint8)])
    q = QUERY_MODES["adapted"].vectors(None, T, pipeline.joint_query)
    np.testing.assert_allclose(q, pipeline.press_map.apply(T), atol=1e-6)
    kept, pipeline.press_map = pipeline.press_map, None
    try:
        np.testing.assert_allclose(QUERY_MODES["adapted"].vectors(None, T, pipeline.joint_query),
                                   T, atol=1e-6)
    finally:
        pipeline.press_map = kept


def test_the_shipped_map_brings_fresh_everyday_presses_to_their_material(pipeline):
    """docs/geometry.md: on everyday presses of a stream neither the fit nor its report drew
    from, the adapted query's top-5 captions are of the pressed material far more often than
    the paper's tactile query's (the tests' 600-entry corpus)."""
    mats, names, _ = material_index(pipeline)
    index = {m: i for i, m in enumerate(names)}
    T, y, _, _ = everyday_presses(pipeline.encoders, index, 4321, 2)
    before = precision_at5(pipeline, mats, names, T, y).mean()
    after = precision_at5(pipeline, mats, names, pipeline.press_map.apply(T), y).mean()
    assert after > before + 0.1, (before, after)


@pytest.mark.slow
def test_train_press_map_cli_fits_saves_and_reports(pipeline, tmp_path, monkeypatch, capsys):
    from ratouch.search import retrieval_side

    monkeypatch.setattr(retrieval_side.RetrievalSide, "load",
                        classmethod(lambda cls, *a, **kw: pipeline))
    out = tmp_path / "map.npz"
    assert main(["train", "press-map", "--fit", "1", "--world", "8", "--balls", "2",
                 "--eval", "1", "--world-eval", "6", "--balls-eval", "1", "--steps", "3",
                 "--router-balls", "2", "--out", str(out)]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["written"] == str(out)
    for when in ("before", "after"):
        assert set(rep["p_at_5"][when]) == {"digit", "gelsight", "mini", "all"}
    m = PressMap.load(out)
    assert m.meta["config"]["steps"] == 3 and m.dim == pipeline.encoders.dim
    assert m.meta["config"]["balls"] == 2 and "12 rigid-ball" in m.meta["fitted_on"]
    assert 0 <= rep["p_at_5"]["after"]["all"]["balls_rigid_top1"] <= 1
    # the regime router, fitted beside the map on its fit streams read alone
    assert m.router is not None and rep["router"] == m.meta["router"]
    assert "6 rigid balls, each read alone" in rep["router"]["fitted_on"]
    assert set(rep["router"]["fresh_read_everyday"]) == {"everyday", "world", "balls"}
    # --router-only: the shipped map's weights as they are, a router fitted onto them
    only = tmp_path / "only.npz"
    assert main(["train", "press-map", "--router-only", "--fit", "1", "--world", "8",
                 "--eval", "1", "--world-eval", "6", "--balls-eval", "1", "--router-balls",
                 "2", "--out", str(only)]) == 0
    rep = json.loads(capsys.readouterr().out)
    got, shipped = PressMap.load(only), PressMap.load(press_map("default-s"))
    for k in ("w1", "b1", "w2", "b2"):
        np.testing.assert_array_equal(getattr(got, k), getattr(shipped, k))
    assert got.router is not None and got.meta["router"] == rep["router"]


def test_fit_press_map_reports_before_and_after(pipeline):
    pm, rep = fit_press_map(pipeline, PressMapConfig(fit_per_kind=1, world=6, eval_per_kind=1,
                                                     world_eval=4, steps=2, router_balls=1))
    assert rep["before"]["all"]["everyday"] == pm.meta["p_at_5"]["before"]["all"]["everyday"]
    assert all(v is None or 0 <= v <= 1 for fam in ("digit", "gelsight", "mini")
               for v in rep["after"][fam].values())
    assert rep["after"]["all"]["everyday"] is not None
