"""Saving and loading the trained modules: round trip, and clear refusals."""

from __future__ import annotations

import json
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grounding_jax as gj
from grounding_jax.core.checkpoint import CheckpointError
from grounding_jax.learn import cacla, esn, tl
from grounding_jax.robot import trained
from grounding_jax.sim import tl_data
from grounding_jax.sim.env import EnvConfig


@pytest.fixture(scope="module")
def modules():
    k1, k2, k3 = jax.random.split(jax.random.key(0), 3)
    hp = tl.TLHyper(hidden=50, replication=20, **tl.TUNED)
    return {"tl_params": tl.init(k1, hp, tl.TLConfig()), "tl_hyper": hp,
            "agent": cacla.init(k2), "net": esn.init(k3).replace(
                w_out=jax.random.normal(k3, (50, 9)))}


def _save(path, m, **kw):
    trained.save(path, m["tl_params"], m["tl_hyper"], m["agent"], cacla.CaclaConfig(),
                 m["net"], esn.ESNConfig(), EnvConfig(), **kw)


def test_save_then_load_gives_the_same_modules(tmp_path, modules):
    _save(tmp_path / "m", modules, extra={"note": "test"})
    robot = gj.load(tmp_path / "m")
    for a, b in zip(jax.tree.leaves((modules["tl_params"], modules["agent"], modules["net"])),
                    jax.tree.leaves((robot.tl.params, robot.al.agent, robot.an.net)),
                    strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert robot.config["extra"] == {"note": "test"}
    # the loaded modules answer as the originals do
    obs = jnp.linspace(-1, 1, 11)
    np.testing.assert_array_equal(robot.al.act(obs),
                                  cacla.actor_apply(modules["agent"].actor, obs)[1])
    data = tl_data.load()
    pos = robot.tl.position(jnp.asarray(data.bitmaps[:5]), jnp.asarray(data.symbols[:5]))
    expect = [int(tl.localize(modules["tl_params"], jnp.asarray(data.bitmaps[i]),
                              jnp.asarray(data.symbols[i]), modules["tl_hyper"]))
              for i in range(5)]
    assert pos.tolist() == expect
    assert robot.tl.localize(0, "red") == expect[3]  # configuration 3 = layout 0, "red"
    a, w = robot.an.name(jnp.zeros((5, 40)), jnp.zeros(50))
    assert a in ("point", "touch", "push") and w in tl_data.TARGET_WORDS
    # saving again replaces the folder whole
    _save(tmp_path / "m", modules)
    assert gj.load(tmp_path / "m").config["extra"] == {}
    assert sorted(p.name for p in tmp_path.iterdir()) == [".lock", "m"]  # the writer lock


def test_load_refuses_what_it_cannot_use(tmp_path, modules, monkeypatch):
    with pytest.raises(CheckpointError, match="no checkpoint config"):
        gj.load(tmp_path / "missing")
    _save(tmp_path / "m", modules)
    cfg_path = tmp_path / "m" / "config.json"
    original = cfg_path.read_text()
    # another package version
    monkeypatch.setattr("grounding_jax.core._version.__version__", "0.0.1")
    with pytest.raises(CheckpointError, match="0.0.1"):
        gj.load(tmp_path / "m")
    monkeypatch.undo()
    # a config edited after saving: refused before anything is built from it
    for edit in ({"al": {"actor_hiden": 40}}, {"al": {"actor_hidden": 30}},
                 {"tl": {"hidden": 7}}):
        cfg = json.loads(original)
        for part, change in edit.items():
            cfg["config"][part].update(change)
        cfg_path.write_text(json.dumps(cfg))
        with pytest.raises(CheckpointError, match="config.json: edited after step 0"):
            gj.load(tmp_path / "m")
    cfg_path.write_text(original)
    # a config this version cannot build, and arrays that do not fit the config's shapes
    cfg = json.loads(original)["config"]
    cfg["al"]["actor_hiden"] = 40
    with pytest.raises(CheckpointError, match="actor_hiden"):
        trained._configs(cfg)
    cfg = json.loads(original)["config"]
    cfg["al"]["actor_hidden"] = 30
    from grounding_jax.core.checkpoint import Checkpointer

    with Checkpointer(tmp_path / "m", trained.KIND, json.loads(original)["config"],
                      read_only=True) as ck, pytest.raises(
            CheckpointError, match="not compatible with the stored shape"):
        ck.restore(0, trained._like(cfg))
    # a damaged array file
    for f in (tmp_path / "m" / "steps").rglob("*"):
        if f.is_file() and f.parent.name == "d":
            f.write_bytes(b"\0" * 10)
    with pytest.raises(CheckpointError, match="steps/0: damaged"):
        gj.load(tmp_path / "m")


def test_perform_compiles_once_per_step_count_and_answers_as_the_modules_do(tmp_path, modules):
    from grounding_jax.learn import al

    _save(tmp_path / "m", modules)
    robot = gj.load(tmp_path / "m")
    outs = [robot.perform("push", "red", layout=3, steps=4),
            robot.perform("touch", "box", layout=7, steps=4)]
    assert list(robot._performers) == [4] and robot._performers[4]._cache_size() == 1
    # the same as running the pieces one by one
    out = outs[1]
    position = robot.tl.localize(7, "box")
    assert out["position"] == ("left", "middle", "right")[position]
    _, traj, hidden = al.make_eval(robot.env_config, 4)(
        robot.al.agent, jax.random.key(0), gj.make_task("touch", position, 7))
    np.testing.assert_allclose(out["trajectory"].obs, traj.obs, atol=1e-5)
    bitmap = jnp.asarray(tl_data.cached_bitmaps()[7], jnp.float32)
    tl_h = robot.tl.hidden_layer(bitmap, jnp.asarray(tl_data.symbol_units(7, "box")))
    assert out["named"] == robot.an.name(hidden, tl_h)
    with pytest.raises(ValueError, match="steps"):
        robot.perform("push", "red", layout=3, steps=0)
    # a command as typed: case and surrounding spaces do not matter, a wrong word still does
    loud = robot.perform(" PUSH ", " Red\t", layout=3, steps=4)
    assert loud["named"] == outs[0]["named"] and loud["position"] == outs[0]["position"]
    np.testing.assert_array_equal(loud["trajectory"].obs, outs[0]["trajectory"].obs)
    with pytest.raises(ValueError, match="target word.*accepted"):
        robot.perform("push", "re d", layout=3, steps=4)


def test_the_paper_familys_agents_are_saved_beside_the_robots_own(tmp_path, modules):
    agents = jax.vmap(cacla.init)(jax.random.split(jax.random.key(4), 3))
    own = jax.tree.map(lambda x: x[1], agents)
    _save(tmp_path / "m", {**modules, "agent": own}, agents=agents, saved_agent=1)
    robot = gj.load(tmp_path / "m")
    assert robot.n_agents == 3 and robot.saved_agent == 1
    np.testing.assert_array_equal(robot.al.agent.actor.w1, agents.actor.w1[1])
    other = robot.with_agent(2)
    np.testing.assert_array_equal(other.al.agent.actor.w1, agents.actor.w1[2])
    # the TL and the AN stay the robot's own; the compiled episodes are shared
    assert other.tl is robot.tl and other.an is robot.an
    assert other._performers is not robot._performers
    for bad in (3, -1, 1.0, True):
        with pytest.raises(ValueError, match=r"i: .*0\.\.2"):
            robot.with_agent(bad)
    # modules saved without them: none to choose from, said so
    _save(tmp_path / "plain", modules)
    plain = gj.load(tmp_path / "plain")
    assert plain.n_agents == 0 and plain.saved_agent is None
    with pytest.raises(ValueError, match="no saved agents"):
        plain.with_agent(0)
    with pytest.raises(ValueError, match="saved_agent"):
        _save(tmp_path / "bad", modules, agents=agents, saved_agent=3)
    assert not (tmp_path / "bad").exists()


def test_save_is_public_and_a_loaded_robot_saves_again_as_the_docs_show(tmp_path):
    robot = gj.load(pathlib.Path(__file__).resolve().parents[1] / "results" / "quick" / "modules")
    gj.save(tmp_path / "mine", robot.tl.params, robot.tl.hyper, robot.al.agent,
            robot.al.config, robot.an.net, robot.an.config, robot.env_config)
    again = gj.load(tmp_path / "mine")
    for a, b in ((robot.tl.params, again.tl.params), (robot.al.agent, again.al.agent)):
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            np.testing.assert_array_equal(x, y)
    assert again.al.config == robot.al.config and again.env_config == robot.env_config
