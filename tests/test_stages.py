"""The stage registry (grounding_jax.paper.stage): typed configs from profiles and the command
line, keys that do not depend on the other stages, results that must be JSON, report
sections."""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import pytest

from grounding_jax.paper import stage


@dataclasses.dataclass(frozen=True)
class ToyConfig:
    rate: float = 0.5
    steps: int = 3
    names: tuple[str, ...] = ("a",)
    verbose: bool = False

    def __post_init__(self) -> None:
        if self.steps < 1:
            raise ValueError(f"steps: {self.steps}; accepted: an int >= 1")


def _toy(**kw) -> stage.Stage:
    def run(key, inputs, out, config):
        return {"draw": float(jax.random.uniform(key)), "steps": config.steps,
                "profile": inputs.profile}

    return stage.Stage(**{"name": "toy", "title": "A toy", "config": ToyConfig, "run": run,
                          "report": lambda res, config: f"drew {res['draw']:.3f}",
                          "profiles": {"paper": {"steps": 10}}, **kw})


def test_configs_come_from_the_profile_and_the_command_line():
    toy = _toy()
    assert toy.make_config("quick") == ToyConfig()
    assert toy.make_config("paper").steps == 10
    cfg = toy.make_config("paper", {"rate": "0.25", "names": "x,y", "verbose": "true"})
    assert cfg == ToyConfig(rate=0.25, steps=10, names=("x", "y"), verbose=True)
    # JSON values (a config read back from metrics.json) come out as the same config
    assert toy.make_config("", json.loads(json.dumps(dataclasses.asdict(cfg)))) == cfg


@pytest.mark.parametrize("changes, needle", [
    ({"rat": "1"}, "accepted fields of stage 'toy': ['rate', 'steps', 'names', 'verbose']"),
    ({"steps": "many"}, "toy.steps: expected int"),
    ({"steps": 2.5}, "toy.steps: expected int"),
    ({"steps": "0"}, "steps: 0; accepted: an int >= 1"),
    ({"verbose": "maybe"}, "toy.verbose: expected true or false"),
])
def test_a_bad_field_is_named_with_what_is_accepted(changes, needle):
    with pytest.raises(ValueError) as e:
        _toy().make_config("quick", changes)
    assert needle in str(e.value)


def test_a_stage_is_checked_when_it_is_made():
    with pytest.raises(ValueError, match="name"):
        _toy(name="Bad Name")
    with pytest.raises(TypeError, match="config"):
        _toy(config=dict)
    with pytest.raises(ValueError, match="steps"):  # a profile's bad field
        _toy(profiles={"paper": {"steps": 0}})


def test_command_line_items_name_a_registered_stage(monkeypatch):
    monkeypatch.setitem(stage._REGISTRY, "toy", _toy())
    got = stage.configs("paper", ["toy.rate=0.1"])
    assert got["toy"] == ToyConfig(rate=0.1, steps=10)
    assert "random_starts" in got  # the package's own stage, found in its folder
    with pytest.raises(ValueError, match="unknown stage 'nope'; accepted stages: .*toy"):
        stage.configs("quick", ["nope.x=1"])
    with pytest.raises(ValueError, match="expected <stage>.<field>=<value>"):
        stage.configs("quick", ["toy.rate"])


def test_a_stages_key_depends_only_on_its_name():
    root = jax.random.key(3)
    a, b = (jax.random.key_data(stage.stage_key(root, n)) for n in ("toy", "other"))
    assert not np.array_equal(a, b)
    np.testing.assert_array_equal(a, jax.random.key_data(stage.stage_key(root, "toy")))


def test_run_all_writes_entries_and_refuses_results_that_are_not_json(tmp_path):
    toy = _toy()
    inputs = stage.Inputs(modules=tmp_path / "modules", profile="quick", backend="mujoco",
                          seed=0)
    root = jax.random.key(0)
    entry = stage.run(toy, root, inputs, tmp_path / "toy", toy.make_config("quick"))
    assert entry["config"] == dataclasses.asdict(ToyConfig())
    assert entry["result"]["steps"] == 3 and entry["result"]["profile"] == "quick"
    assert entry["result"]["draw"] == float(jax.random.uniform(stage.stage_key(root, "toy")))
    assert entry["wall_s"] >= 0
    bad = _toy(run=lambda *a: {"array": np.zeros(2)})
    with pytest.raises(TypeError, match="JSON serializable"):
        stage.run(bad, root, inputs, tmp_path / "bad", bad.make_config("quick"))


def test_report_sections_use_the_stage_and_say_when_one_is_missing(monkeypatch):
    monkeypatch.setitem(stage._REGISTRY, "toy", _toy())
    result = {"profile": "quick", "stages": {
        "toy": {"config": dataclasses.asdict(ToyConfig()), "result": {"draw": 0.25}},
        "gone": {"config": {}, "result": {}}}}
    text = "\n".join(stage.report_sections(result))
    assert "## A toy" in text and "drew 0.250" in text
    assert "## Stage `gone`" in text and "Not registered" in text
    assert stage.report_sections({"profile": "quick"}) == []


@pytest.mark.parametrize("changes, needle", [
    ({"touch_still_penalty": -1.0}, "touch_still_penalty: -1.0; accepted: >= 0"),
    ({"variants": ("paper_still",)}, "variants: .*paper_memory_touch_pose_still"),
    ({"save": "paper_memory"}, "save: 'paper_memory'; accepted: one of variants"),
    ({"start_ramp": 2.0}, r"start_noise, start_ramp: 0.5, 2.0; accepted: each in \[0, 1\]"),
    ({"still_extra": -5}, "still_extra: -5; accepted: an int >= 0"),
    ({"push_other_penalty": float("nan")}, "push_other_penalty: nan; accepted: a finite"),
])
def test_a_bad_touch_memory_config_is_named(changes, needle):
    with pytest.raises(ValueError, match=needle):
        stage.stages()["touch_memory"].make_config("quick", changes)


def test_only_the_variants_that_hold_still_get_still_extra():
    from grounding_jax.paper.stages import touch_memory as tm
    config = stage.stages()["touch_memory"].make_config(
        "paper", {"phase2": 10, "still_extra": 20, "touch_bonus": 0.5})
    assert tm.variant_plan("paper_memory", config) == ("paper_memory", 10, {}, None)
    ts, phase2, fields, heads = tm.variant_plan("paper_memory_touch_pose_still", config)
    assert (ts, phase2, heads) == ("paper_memory_touch_pose", 30, (0, 1, 0))
    assert fields == {"touch_bonus": 0.5, "touch_still_penalty": 3.0}
    _, _, fields, _ = tm.variant_plan("paper_memory_touch_pose_still_avoid", config)
    assert fields == {"touch_bonus": 0.5, "touch_still_penalty": 3.0, "push_other_penalty": -0.5}
    _, phase2, fields, _ = tm.variant_plan("paper_touch_pose_still_starts", config)
    assert phase2 == 30 and fields["start_noise"] == 0.5 and fields["start_ramp"] == 0.5
    assert "start_by_action" not in fields
    _, phase2, fields, _ = tm.variant_plan("paper_memory_touch_pose_still_avoid_push_starts",
                                           config)
    assert phase2 == 30 and fields == {
        "touch_bonus": 0.5, "touch_still_penalty": 3.0, "start_noise": 0.5, "start_ramp": 0.5,
        "start_by_action": [0.0, 0.0, 1.0], "push_other_penalty": -0.5}
    _, phase2, _, _ = tm.variant_plan("paper_touch_pose_still", dataclasses.replace(
        config, still_extra=0))
    assert phase2 == 10
