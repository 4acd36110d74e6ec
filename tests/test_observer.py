"""The observer (``Robot.watch``): motor resonance's parts with analytic answers, the robot
watching its own episodes (the true command explains them exactly), batches, bad input, and
the paper family's agents saved with the modules."""

from __future__ import annotations

import dataclasses
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grounding_jax as gj
from grounding_jax.robot import observer
from grounding_jax.sim import scene, tl_data

ROOT = pathlib.Path(__file__).resolve().parent.parent
STEPS = 25  # short episodes: the resonance needs only a few steps to tell commands apart


@pytest.fixture(scope="module")
def robot():
    return gj.load(ROOT / "results" / "paper" / "modules")


@pytest.fixture(scope="module")
def pushed(robot):
    """The committed robot's own "push red" in layout 3, and "point box" in layout 7."""
    return (robot.perform("push", "red", layout=3, steps=STEPS),
            robot.perform("point", "box", layout=7, steps=STEPS, key=jax.random.key(2)))


def test_commands_scores_and_words_have_their_analytic_answers():
    a, p = observer.commands(3)
    assert a.tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2] and p.tolist() == [0, 1, 2] * 3
    errors = jnp.asarray(np.arange(1, 19, dtype=np.float32).reshape(2, 3, 3))
    np.testing.assert_allclose(observer.score(errors),
                               np.log(np.arange(1, 10) + 1e-12).reshape(3, 3)
                               + np.log(np.arange(10, 19) + 1e-12).reshape(3, 3), rtol=1e-6)
    scores = jnp.asarray([[3.0, 2.0, 5.0], [4.0, -1.0, 0.0], [9.0, 9.0, 9.0]])
    assert tuple(int(x) for x in observer.best(scores)) == (1, 1)
    probs = jnp.asarray([[0.1, 0.2, 0.7], [0.9, 0.05, 0.3], [0.2, 0.6, 0.1]] * 2)
    assert int(observer.paper_word(probs, 0)) == 1 and int(observer.paper_word(probs, 2)) == 0
    est = jnp.asarray([[0.0, 0.0], [1.0, 1.0], [0.2, 0.1], [5.0, 5.0], [0.9, 1.2], [3, 3]])
    assert int(observer.free_word(est, jnp.asarray([0.25, 0.1]))) == 2
    shapes, colours = scene.LAYOUTS[5]
    for slot in range(3):  # the slot's shape and colour name it; the others' do not
        for w, word in enumerate(tl_data.TARGET_WORDS):
            assert observer.names_target(5, w, slot) == (word in (shapes[slot], colours[slot]))


def test_watching_its_own_episode_finds_the_command_that_made_it(robot, pushed):
    push, point = pushed
    res = robot.resonance(push)  # perform's output dict is taken as it is
    slot = scene.POSITIONS.index(push["true_position"])
    # its own move from each watched state is the watched step itself: no mismatch at all
    assert res["errors"].shape == (2, 3, 3) and np.all(res["errors"][:, 2, slot] == 0)
    others = np.delete(res["errors"].reshape(2, 9), 2 * 3 + slot, axis=1)
    assert np.all(others > 0)
    assert (res["action"], res["position"]) == ("push", push["true_position"])
    assert res["named"][0] == "push" and res["named"] == robot.watch(push["trajectory"])
    assert observer.names_target(3, tl_data.word_index(res["word"]), slot)
    assert observer.names_target(3, tl_data.word_index(res["named"][1]), slot)
    # a batch: one call, one answer per episode, the same answers as one at a time
    batch = jax.tree.map(lambda *x: jnp.stack(x), push["trajectory"], point["trajectory"])
    rows = robot.resonance(batch)
    assert [r["action"] for r in rows] == ["push", "point"]
    np.testing.assert_array_equal(rows[0]["errors"], res["errors"])
    assert robot.watch(batch) == [rows[0]["named"], rows[1]["named"]]
    assert rows[1]["position"] == point["true_position"] and rows[1]["named"][0] == "point"


def test_the_observer_never_reads_the_watched_robots_command(robot, pushed):
    push, _ = pushed
    traj = push["trajectory"]
    ts = robot.env_config.tasks
    # the command's units in the observations and the task's action and slot scrambled
    told = traj.replace(obs=traj.obs.at[:, ts.obs_action.start:].set(0.0),
                        task=traj.task.replace(action=jnp.zeros_like(traj.task.action),
                                               position=jnp.zeros_like(traj.task.position)))
    a, b = robot.resonance(traj), robot.resonance(told)
    np.testing.assert_array_equal(a["errors"], b["errors"])
    assert a["named"] == b["named"]


def test_the_free_robot_watches_its_own_episode_anywhere_on_the_table(robot, renderer):
    out = robot.perform("touch", "green", layout=5, steps=STEPS, placement="random",
                        key=jax.random.key(3))
    res = robot.resonance(out)
    assert (res["action"], res["position"]) == ("touch", out["position"])
    assert res["named"] == robot.watch(out["trajectory"]) and res["named"][0] == "touch"
    placed = out["placement"]
    # the word it chose is the one whose continuous-TL estimate lies nearest that object
    image = renderer.render(5, placed)
    est = np.stack([robot.free.localize(image, 5, w) for w in tl_data.TARGET_WORDS])
    slot = scene.POSITIONS.index(out["position"])
    assert res["word"] == tl_data.TARGET_WORDS[int(np.argmin(
        np.linalg.norm(est - placed[slot, :2], axis=1)))]


def test_bad_trajectories_are_refused_naming_the_field(robot, pushed):
    push, _ = pushed
    traj = push["trajectory"]
    with pytest.raises(ValueError, match="trajectory: expected env states"):
        robot.watch(np.zeros((10, 11)))
    with pytest.raises(ValueError, match=r"trajectory: .*accepted: \[T, 11\]"):
        robot.watch(traj.replace(obs=traj.obs[:, :9]))
    with pytest.raises(ValueError, match="T >= 2"):
        robot.watch(jax.tree.map(lambda x: x[:1], traj))
    placed = traj.replace(task=traj.task.replace(
        placement=jnp.zeros((STEPS, 3, 3), jnp.float32)))
    with pytest.raises(ValueError, match="no free-family robot"):
        dataclasses.replace(robot, free=None).watch(placed)
    with pytest.raises(ValueError, match="action_scale"):
        robot.watch(traj, params=gj.EnvParams(action_scale=-1.0))


def test_the_observer_pages_example_runs_on_the_committed_modules(monkeypatch, capsys):
    import re

    text = (ROOT / "docs" / "observer.md").read_text()
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    assert "with_agent(3)" in code  # another agent, from another seed, acts
    monkeypatch.chdir(ROOT)
    exec(compile(code, "docs/observer.md", "exec"), {})
    named = capsys.readouterr().out.splitlines()[0]
    action, word = re.fullmatch(r"\('(\w+)', '(\w+)'\)", named).groups()
    slot = tl_data.label_of(7, tl_data.word_index("blue"))
    assert action == "push" and observer.names_target(7, tl_data.word_index(word), slot)
