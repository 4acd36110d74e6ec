"""The env on the C MuJoCo backend: semantics, rewards, termination, batching, bad input."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grounding_jax as gj
from grounding_jax.sim import env as env_mod
from grounding_jax.sim import scene


def _paper_eq1(deg: np.ndarray) -> np.ndarray:
    """Eq. 1 exactly as printed: j = 2 (j' + |Min|) / (|Min| + |Max|) - 1."""
    lo, hi = np.abs(scene.PAPER_LIMITS_DEG[:, 0]), np.abs(scene.PAPER_LIMITS_DEG[:, 1])
    return 2 * (deg + lo) / (lo + hi) - 1


def test_eq1_maps_the_paper_limits_to_plus_minus_one():
    lo = np.radians(scene.PAPER_LIMITS_DEG[:, 0])
    hi = np.radians(scene.PAPER_LIMITS_DEG[:, 1])
    np.testing.assert_allclose(env_mod.scale_joints(jnp.asarray(lo)), -1.0, atol=1e-6)
    np.testing.assert_allclose(env_mod.scale_joints(jnp.asarray(hi)), 1.0, atol=1e-6)
    home = scene.HOME_POSE_DEG
    np.testing.assert_allclose(env_mod.scale_joints(jnp.radians(jnp.asarray(home))),
                               _paper_eq1(home), atol=1e-6)
    # hand value: pitch -60 deg -> 2 * 35 / 185 - 1
    assert abs(float(env_mod.scale_joints(jnp.radians(jnp.asarray(home)))[0])
               - (2 * 35 / 185 - 1)) < 1e-6
    j = jnp.asarray([0.3, -0.2, 0.9, -0.99])
    np.testing.assert_allclose(env_mod.scale_joints(env_mod.unscale_joints(j)), j, atol=1e-6)


def test_reset_observation(env_c):
    st = env_c.reset(jax.random.key(0), gj.make_task("touch", "right", 5))
    np.testing.assert_allclose(st.obs[:4], _paper_eq1(scene.HOME_POSE_DEG), atol=1e-5)
    np.testing.assert_array_equal(st.obs[4:], [0, 0, 1, 0, 0, 0, 1])
    assert st.obs.shape == (env_mod.OBS_SIZE,) and not bool(st.done)
    # layout 5 = box, sphere... read the objects back from qpos: each shape at its slot
    slots = scene.layout_shape_slots()[5]
    idx = scene.index()
    np.testing.assert_allclose(st.qpos[idx.object_qpos[:, :3]],
                               scene.object_positions()[slots], atol=1e-6)



def test_the_task_vocabulary_sets_the_observation_layout_and_the_sizes(env_c):
    from grounding_jax.learn import cacla, esn
    from grounding_jax.sim import tasks

    st = env_c.reset(jax.random.key(0), gj.make_task("touch", "right", 5))
    assert st.obs.shape == (tasks.OBS_SIZE,)
    np.testing.assert_array_equal(st.obs[tasks.OBS_ACTION], np.eye(tasks.N_ACTIONS)[1])
    np.testing.assert_array_equal(st.obs[tasks.OBS_POSITION], np.eye(tasks.N_POSITIONS)[2])
    sw = env_c.set_task(st, gj.make_task("push", "left", 5))
    np.testing.assert_array_equal(sw.obs[tasks.OBS_ACTION], np.eye(tasks.N_ACTIONS)[2])
    np.testing.assert_array_equal(sw.obs[tasks.OBS_POSITION], np.eye(tasks.N_POSITIONS)[0])
    np.testing.assert_array_equal(sw.obs[tasks.OBS_JOINTS], st.obs[tasks.OBS_JOINTS])
    agent = cacla.init(jax.random.key(0))
    hidden, action = cacla.actor_apply(agent.actor, st.obs)
    assert action.shape == (tasks.ACTION_SIZE,) and cacla.critic_apply(agent.critic,
                                                                          st.obs).shape == ()
    assert esn.ESNConfig().n_out == tasks.N_ACTIONS + len(tasks.TARGET_WORDS)


def test_a_memory_holds_the_last_steps_joints_and_actions_newest_first():
    from grounding_jax.learn import cacla
    from grounding_jax.sim import tasks

    ts = tasks.get("paper_memory")
    assert ts.memory == 2 and ts.obs_size == tasks.OBS_SIZE + 2 * 2 * tasks.N_JOINTS
    env = gj.Env(gj.EnvConfig(task_set="paper_memory"))
    s0 = env.reset(jax.random.key(0), gj.make_task("touch", "middle", 0, "paper_memory"))
    joints = lambda s: np.asarray(s.obs[:4])  # noqa: E731
    mem = lambda s: np.asarray(s.obs[ts.obs_memory]).reshape(4, 4)  # noqa: E731
    # at reset: the reset joints stand in for the steps before, no actions yet
    np.testing.assert_array_equal(mem(s0), [joints(s0), joints(s0), np.zeros(4), np.zeros(4)])
    np.testing.assert_array_equal(s0.obs[:tasks.OBS_SIZE],
                                  env_mod.Env(env_mod.EnvConfig()).reset(
                                      jax.random.key(0), gj.make_task("touch", "middle", 0)).obs)
    a1, a2 = jnp.array([0.1, 0.2, 0.3, 0.4]), jnp.array([-0.1, 0.0, 0.0, 0.5])
    s1 = env.step(s0, a1)
    s2 = env.step(s1, a2)
    np.testing.assert_array_equal(mem(s1), [joints(s0), joints(s0), a1, np.zeros(4)])
    np.testing.assert_array_equal(mem(s2), [joints(s1), joints(s0), a2, a1])
    # a goal switch keeps the memory; the learner's input size follows the task set
    sw = env.set_task(s2, gj.make_task("push", "left", 0, "paper_memory"))
    np.testing.assert_array_equal(mem(sw), mem(s2))
    agent = cacla.init(jax.random.key(0), cacla.CaclaConfig(task_set="paper_memory"))
    assert cacla.actor_apply(agent.actor, s2.obs)[1].shape == (tasks.ACTION_SIZE,)
    with pytest.raises(ValueError, match="memory"):
        dataclasses.replace(ts, name="bad", memory=-1)


def test_a_fourth_action_is_one_task_set_and_every_size_follows():
    """A dummy fourth action ("hover": stay 10 cm from the target) defined only in a task
    set: env, learner, ESN, the trainer's task draw and the success rule all follow."""
    from grounding_jax.learn import al, cacla, esn
    from grounding_jax.paper import al_eval
    from grounding_jax.sim import tasks

    hover = tasks.Action(
        "hover", reward=lambda t, p: -jnp.abs(t["palm_target_dist"] - 0.1),
        success=lambda q: q["target_moved"] < 0.005)
    four = tasks.register(tasks.TaskSet("test_four", (*tasks.PAPER.actions, hover)))
    assert (four.n_actions, four.obs_size, four.sentence_size) == (4, 12, 10)

    env = gj.make_env("mujoco", task_set="test_four")
    task = gj.make_task("hover", "middle", 3, task_set="test_four")
    st = env.reset(jax.random.key(0), task)
    assert st.obs.shape == (12,)
    np.testing.assert_array_equal(st.obs[four.obs_action], np.eye(4)[3])
    np.testing.assert_array_equal(st.obs[four.obs_position], np.eye(3)[1])
    nxt = env.step(st, jnp.zeros(4))
    dist = float(nxt.metrics["palm_target_dist"])
    assert float(nxt.reward) == pytest.approx(-abs(dist - 0.1), abs=1e-6)
    # the paper's three keep their rewards under the larger set
    push = env.step(env.reset(jax.random.key(0), gj.make_task("push", "middle", 3)), jnp.zeros(4))
    assert float(push.reward) == pytest.approx(-dist, abs=1e-6)
    with pytest.raises(ValueError, match="action: unknown value 'hover'.*'push'"):
        gj.make_task("hover", "middle")  # not in the paper's set

    c = cacla.CaclaConfig(task_set="test_four")
    agent = cacla.init(jax.random.key(0), c)
    hidden, action = cacla.actor_apply(agent.actor, st.obs)
    assert agent.actor.w1.shape[0] == 12 and action.shape == (4,)
    assert cacla.critic_apply(agent.critic, st.obs).shape == ()
    cfg = al.ALConfig(env=env.config, learner=c)
    assert cfg.actions == (0, 1, 2, 3)
    with pytest.raises(ValueError, match="learner.task_set"):
        al.ALConfig(env=env.config)  # a paper-sized learner in a four-action env

    e = esn.ESNConfig(task_set="test_four")
    assert e.n_out == 10 and esn.init(jax.random.key(0), e).w_out.shape[1] == 10
    d = esn.targets(jnp.asarray([3]), jnp.asarray([5]), four.n_actions)
    assert [int(i[0]) for i in esn.decode(d, four.n_actions)] == [3, 5]
    with pytest.raises(ValueError, match="n_out"):
        esn.ESNConfig(task_set="test_four", n_out=9)

    traj = jax.tree.map(lambda x: x[None], nxt)
    ok = al_eval.episode_success(traj, task, task_set=four)
    assert float(ok["success"]) == float(float(nxt.metrics["target_moved"]) < 0.005) == 1.0
    with pytest.raises(ValueError, match="task_set: unknown value 'nope'"):
        gj.make_env("mujoco", task_set="nope")


def _expected_reward(state, action: int, position: int, layout: int) -> float:
    """The paper's three rewards, computed here from the raw state with NumPy."""
    idx = scene.index()
    q = np.degrees(np.asarray(state.qpos)[idx.arm_qpos])
    if action == 0:
        pointing = np.degrees(scene.pointing_configs()[position])
        return -np.abs(_paper_eq1(q) - _paper_eq1(pointing)).sum()
    shape = list(scene.layout_shape_slots()[layout]).index(position)
    palm = np.asarray(state.sensordata)[idx.sensor_palm_pos]
    start = scene.object_positions()[position]
    r = -np.linalg.norm(palm - start)
    if action == 1:
        found = np.asarray(state.sensordata)[idx.sensor_contact].sum(axis=1) > 0
        if found[shape]:
            r += -0.3
        if np.delete(found, shape).any():
            r += -0.5
    return r


@pytest.mark.parametrize("action", range(3))
def test_rewards_match_hand_computed_values(env_c, run_c, push_waypoints, action):
    # push the middle object of layout 7 with the task's action set to each of the three
    task = gj.make_task(action, "middle", 7)
    first, traj = run_c(push_waypoints[1], task, gj.EnvParams())
    touched = np.asarray(traj.metrics["touched_target"])
    assert touched.any(), "the scripted push must touch the target"
    for t in [0, int(np.argmax(touched)), 74]:
        st = jax.tree.map(lambda x, t=t: x[t], traj)
        assert float(st.reward) == pytest.approx(_expected_reward(st, action, 1, 7), abs=1e-4)
    assert float(first.reward) == pytest.approx(_expected_reward(first, action, 1, 7), abs=1e-4)


def test_push_can_pay_for_moving_the_target_up_to_a_cap(run_c, push_waypoints):
    from grounding_jax.sim import tasks
    task = gj.make_task("push", "middle", 7)
    _, plain = run_c(push_waypoints[1], task, gj.EnvParams())
    _, paid = run_c(push_waypoints[1], task, gj.EnvParams(push_moved_bonus=5.0))
    moved = np.asarray(plain.metrics["target_moved"])
    assert moved[-1] > tasks.PUSH_MOVED  # the scripted push moves it
    extra = np.asarray(paid.reward) - np.asarray(plain.reward)
    np.testing.assert_allclose(extra, 5.0 * np.minimum(moved, tasks.PUSH_MOVED_CAP), atol=1e-5)
    with pytest.raises(ValueError, match="push_moved_bonus: must be >= 0"):
        gj.EnvParams(push_moved_bonus=-1.0).validate()


def test_push_can_pay_for_touching_or_moving_another_object(run_c, push_waypoints):
    # task: push the middle object; the script pushes the left one
    task = gj.make_task("push", "middle", 0)
    _, plain = run_c(push_waypoints[0], task, gj.EnvParams())
    _, paid = run_c(push_waypoints[0], task, gj.EnvParams(push_other_penalty=-0.5))
    other = (np.asarray(plain.metrics["touched_other"]) > 0) | (
        np.asarray(plain.metrics["wrong_moved"]) > 0)
    assert other.any() and not other.all()
    extra = np.asarray(paid.reward) - np.asarray(plain.reward)
    np.testing.assert_allclose(extra, np.where(other, -0.5, 0.0), atol=1e-6)


def test_touch_penalty_for_another_object(run_c, push_waypoints):
    # task: touch the middle object; the script pushes the left one
    _, traj = run_c(push_waypoints[0], gj.make_task("touch", "middle", 0), gj.EnvParams())
    other = np.asarray(traj.metrics["touched_other"]) > 0
    assert other.any()
    t = int(np.argmax(other))
    st = jax.tree.map(lambda x: x[t], traj)
    assert float(st.reward) == pytest.approx(_expected_reward(st, 1, 1, 0), abs=1e-4)
    assert float(st.reward) < -float(st.metrics["palm_target_dist"]) - 0.49


@pytest.mark.parametrize("position", range(3))
def test_scripted_push_moves_the_target_and_not_the_others(run_c, push_waypoints, position):
    first, traj = run_c(push_waypoints[position], gj.make_task("push", position, 0),
                        gj.EnvParams())
    idx = scene.index()
    moved = np.linalg.norm(np.asarray(traj.qpos[-1])[idx.object_qpos[:, :3]]
                           - np.asarray(first.qpos)[idx.object_qpos[:, :3]], axis=1)
    target_shape = list(scene.layout_shape_slots()[0]).index(position)
    assert moved[target_shape] > 0.02
    assert np.delete(moved, target_shape).max() < 1e-3
    assert not np.asarray(traj.metrics["wrong_moved"]).any()
    assert int(np.asarray(traj.done).argmax()) == 74  # runs the full 75 steps


@pytest.mark.parametrize("extra", [0, 3, 6])
def test_bumping_a_wrong_object_ends_the_episode_after_the_extra_steps(run_c, push_waypoints,
                                                                       extra):
    params = gj.EnvParams(wrong_move_extra_steps=extra)
    _, traj = run_c(push_waypoints[0], gj.make_task("push", "middle", 0), params)
    wrong = np.asarray(traj.metrics["wrong_moved"]) > 0
    done = np.asarray(traj.done)
    assert wrong.any()
    first_wrong = int(np.argmax(wrong))  # traj index t holds the state after step t + 1
    assert int(np.argmax(done)) == first_wrong + extra
    assert done[first_wrong + extra:].all() and not done[: first_wrong + extra].any()
    assert int(traj.wrong_since[-1]) == first_wrong + 1


def test_vmapped_batch_equals_a_loop_of_single_envs(env_c):
    keys = jax.random.split(jax.random.key(1), 4)
    tasks = gj.Task(action=jnp.array([0, 1, 2, 0], jnp.int32),
                    position=jnp.array([0, 1, 2, 2], jnp.int32),
                    layout=jnp.array([0, 7, 35, 12], jnp.int32))
    params = gj.EnvParams(start_noise=0.3)
    actions = jax.random.uniform(jax.random.key(2), (5, 4, 4), minval=-1, maxval=1)

    def run(key, task, acts):
        st = env_c.reset(key, task, params)
        for a in acts:
            st = env_c.step(st, a, params)
        return st

    batched = jax.jit(jax.vmap(run))(keys, tasks, jnp.swapaxes(actions, 0, 1))
    single = jax.jit(run)
    for i in range(4):
        one = single(keys[i], jax.tree.map(lambda x, i=i: x[i], tasks), actions[:, i])
        for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(batched), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b)[i], rtol=0, atol=1e-6)


def test_step_keeps_the_state_pytree_structure_and_dtypes(env_c):
    st = env_c.reset(jax.random.key(0), gj.make_task("point", "left"))
    nxt = env_c.step(st, jnp.zeros(4))
    assert jax.tree.structure(st) == jax.tree.structure(nxt)
    for a, b in zip(jax.tree.leaves(st), jax.tree.leaves(nxt), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype


def test_action_moves_the_joints_by_a_third(env_c):
    st = env_c.reset(jax.random.key(0), gj.make_task("point", "left"))
    a = jnp.array([0.3, -0.3, 0.3, 0.3])
    nxt = env_c.step(st, a)
    np.testing.assert_allclose(nxt.info["ctrl"], env_mod.unscale_joints(st.obs[:4] + a / 3),
                               atol=1e-5)
    # the servos get most of the way within one RL step
    moved = np.asarray(nxt.obs[:4] - st.obs[:4])
    assert np.all(np.abs(moved - np.asarray(a) / 3) < 0.25 * np.abs(np.asarray(a) / 3))


def test_commands_are_clipped_to_the_model_joint_limits(env_c):
    st = env_c.reset(jax.random.key(0), gj.make_task("point", "left"))
    rng = scene.index().joint_range
    for _ in range(5):  # +1 scaled pitch is +31 deg a step; the model allows up to +10 deg
        st = env_c.step(st, jnp.array([1.0, 0.0, 0.0, 0.0]))
        ctrl = np.asarray(st.info["ctrl"])
        assert np.all(ctrl >= rng[:, 0] - 1e-6) and np.all(ctrl <= rng[:, 1] + 1e-6)
    assert ctrl[0] == pytest.approx(rng[0, 1], abs=1e-6)
    assert float(st.qpos[scene.index().arm_qpos[0]]) == pytest.approx(rng[0, 1], abs=0.01)


def test_nan_action_is_no_move_and_is_counted(env_c):
    st = env_c.reset(jax.random.key(0), gj.make_task("point", "left"))
    a = jnp.array([jnp.nan, 0.5, jnp.nan, -0.5])
    nan_step = env_c.step(st, a)
    ref = env_c.step(st, jnp.array([0.0, 0.5, 0.0, -0.5]))
    assert np.isfinite(np.asarray(nan_step.qpos)).all()
    np.testing.assert_array_equal(np.asarray(nan_step.qpos), np.asarray(ref.qpos))
    assert float(nan_step.metrics["nan_actions"]) == 2.0


def test_random_start_poses(env_c):
    params = gj.EnvParams(start_noise=0.4)
    keys = jax.random.split(jax.random.key(3), 8)
    task = gj.make_task("point", "left")
    obs = np.stack([np.asarray(env_c.reset(k, task, params).obs[:4]) for k in keys])
    home = _paper_eq1(scene.HOME_POSE_DEG)
    assert np.all(np.abs(obs - home) <= 0.4 + 1e-5)
    assert np.std(obs, axis=0).min() > 0.05  # really random
    again = np.asarray(env_c.reset(keys[0], task, params).obs[:4])
    np.testing.assert_array_equal(again, obs[0])  # and reproducible from the key


def test_goal_switch_mid_episode(env_c):
    st = env_c.reset(jax.random.key(0), gj.make_task("point", "left"))
    for _ in range(3):
        st = env_c.step(st, jnp.zeros(4))
    switched = env_c.set_task(st, gj.make_task("push", "right"))
    np.testing.assert_array_equal(switched.obs[5:], [0, 0, 1, 0, 0, 1])
    nxt = env_c.step(switched, jnp.zeros(4))
    assert float(nxt.reward) == pytest.approx(-float(nxt.metrics["palm_target_dist"]), abs=1e-6)
    assert int(nxt.step) == 4


@pytest.mark.parametrize("kwargs, field", [
    (dict(action="grab", position="left"), "action"),
    (dict(action="push", position="top"), "position"),
    (dict(action="push", position="left", layout=36), "layout"),
    (dict(action="push", position="left", layout="box/red sphere/green"), "layout"),
    (dict(action=3, position="left"), "action"),
])
def test_bad_task_names_raise_with_field_and_accepted_values(kwargs, field):
    with pytest.raises(ValueError, match=field) as err:
        gj.make_task(**kwargs)
    assert "accepted" in str(err.value)


def test_bad_backend_and_config():
    with pytest.raises(ValueError, match=r"backend.*accepted values.*mujoco.*mjx"):
        gj.make_env("bullet")
    with pytest.raises(ValueError, match="substeps"):
        gj.EnvConfig(substeps=0)
    with pytest.raises(ValueError, match="episode_length"):
        gj.EnvConfig(episode_length=2.5)


def test_bad_action_shape_and_task_range(env_c):
    st = env_c.reset(jax.random.key(0), gj.make_task("push", "left"))
    with pytest.raises(ValueError, match=r"action: expected shape \(4,\)"):
        env_c.step(st, jnp.zeros(3))
    bad = gj.Task(action=jnp.int32(0), position=jnp.int32(3), layout=jnp.int32(0))
    with pytest.raises(ValueError, match="task.position"):
        env_c.reset(jax.random.key(0), bad)
    with pytest.raises(ValueError, match="start_noise"):
        env_c.reset(jax.random.key(0), gj.make_task("push", "left"), gj.EnvParams(start_noise=-1))


def test_a_finished_episode_is_absorbing(env_c):
    s = env_c.reset(jax.random.key(0), gj.make_task("push", "left"))
    s = env_c.step(s, jnp.ones(4)).replace(done=jnp.asarray(True))
    after = env_c.step(s, -jnp.ones(4))
    for a, b in zip(jax.tree.leaves(s), jax.tree.leaves(after), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_reset_where_starts_a_new_episode_only_where_asked(env_c):
    keys = jax.random.split(jax.random.key(3), 2)
    tasks = gj.Task(action=jnp.array([1, 2], jnp.int32), position=jnp.array([0, 2], jnp.int32),
                    layout=jnp.array([4, 9], jnp.int32))
    params = gj.EnvParams(start_noise=0.3)

    def moved(key, task):
        return env_c.step(env_c.reset(key, task, params), jnp.ones(4), params)

    old = jax.vmap(moved)(keys, tasks)
    new_keys = jax.random.split(jax.random.key(4), 2)
    new_tasks = tasks.replace(action=jnp.array([0, 0], jnp.int32))
    out = jax.jit(jax.vmap(lambda w, s, k, t: env_c.reset_where(w, s, k, t, params)))(
        jnp.array([True, False]), old, new_keys, new_tasks)
    fresh = env_c.reset(new_keys[0], jax.tree.map(lambda x: x[0], new_tasks), params)
    for a, b, c in zip(jax.tree.leaves(out), jax.tree.leaves(fresh), jax.tree.leaves(old),
                       strict=True):
        np.testing.assert_allclose(np.asarray(a)[0], np.asarray(b), rtol=0, atol=1e-6)
        np.testing.assert_array_equal(np.asarray(a)[1], np.asarray(c)[1])
    assert int(out.step[0]) == 0 and int(out.step[1]) == 1


def test_the_pointing_poses_are_public_and_scaled_as_the_observation(env_c):
    poses = np.asarray(env_c.pointing_poses)
    assert poses.shape == (3, 4) and np.all(np.abs(poses) <= 1)
    # eq. 1 of the paper, on the stored IK poses (radians) and the paper's joint limits
    lo, hi = np.radians([[-95, 0, -37, -6], [90, 161, 100, 106]])
    want = 2 * (np.asarray(scene.pointing_configs()) - lo) / (hi - lo) - 1
    np.testing.assert_allclose(poses, want, atol=1e-5)
