"""`ratouch train all` (`ratouch.ship.retrain.train_all`) through the CLI, every step a
recording stand-in: the shipped weights are retrained in dependency order (the geometry
first; per encoder set of the chain the retriever, the trust calibration, the touch gate, the
press map, the generators, the reader and the text system's generator; the cascade last), each
step's report printed, and nothing written where the stand-ins are not told to."""

from __future__ import annotations

import json
from types import SimpleNamespace

from ratouch.cli import main
from ratouch.encoders.factory import CHAIN_SETS, ENCODER_ONLY_SETS
from ratouch.ship import retrain


def test_train_all_runs_every_step_in_dependency_order(tmp_path, monkeypatch, capsys):
    calls: list[tuple[str, str]] = []

    def saved(what: str):
        return SimpleNamespace(save=lambda path: calls.append(("save", what)), meta={},
                               measure="agree", thresholds=(0.5,))

    def step(what: str, value):
        def run(name=None, *args, **kwargs):
            calls.append((what, name if isinstance(name, str) else ""))
            return value
        return run

    patches = {
        "calibrate_geometry": lambda seed: (calls.append(("geometry", "")),
                                            (saved("geometry"), {"digit": {"presses": [1]}}))[1],
        "geometry_calibration": lambda: tmp_path / "geometry.json",
        "shipped_weights": lambda name: tmp_path / "enc" / name,
        "train_encoders": lambda tc, **kw: (calls.append(("encoders", tc.model)), (None, {}))[1],
        "default_corpus": step("corpus", None),
        "retriever_recipe": step("retriever", {}),
        "create_model": lambda name: name,
        "calibrate": lambda model, cfg, progress=True: (calls.append(("trust", model)),
                                                        saved("trust"))[1],
        "trust_calibration": lambda name: tmp_path / "trust" / name,
        "gate_recipe": step("gate", {}),
        "press_map_recipe": step("press_map", {"written": "x"}),
        "generator_weights": lambda name, kind: tmp_path / "gen" / name / kind,
        "generator_recipe": step("generators", {}),
        "reader_recipe": step("reader", (None, {"history": [1]})),
        "text_arm_recipe": step("text", (None, {})),
        "RATouchPipeline": SimpleNamespace(load=lambda name, progress=True: name),
        "calibrate_cascade": lambda pipes, cfg: (calls.append(("cascade", "+".join(pipes))),
                                                 saved("cascade"))[1],
        "cascade_calibration": lambda name: tmp_path / "cascade.json",
    }
    for name, value in patches.items():
        monkeypatch.setattr(retrain, name, value)
    assert main(["train", "all"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    assert lines[0] == {"geometry": {"digit": {}}}  # its per-press rows left out
    assert any(r.get("press_map") == CHAIN_SETS[0] for r in lines)
    assert "press_map_" + CHAIN_SETS[0] in lines[-1]["seconds"]

    order = [what for what, _ in calls]
    assert order[:2] == ["geometry", "save"] and order[-2:] == ["cascade", "save"]
    assert [n for w, n in calls if w == "encoders"] == [*CHAIN_SETS, *ENCODER_ONLY_SETS]
    for name in CHAIN_SETS:
        mine = [w for w, n in calls if n == name and w != "corpus"]
        assert mine == ["encoders", "retriever", "trust", "gate", "press_map", "generators",
                        "reader", "text"], (name, mine)
    # the corpus is re-embedded for every set after all encoders are trained
    first_corpus = order.index("corpus")
    assert all(w != "encoders" for w in order[first_corpus:])
