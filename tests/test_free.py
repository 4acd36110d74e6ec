"""The free family: the pointing map, the actor told the target's coordinates, a moving target,
training on random placements, and the robot that looks before it acts."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grounding_jax as gj
from grounding_jax.core.checkpoint import CheckpointError
from grounding_jax.learn import al, cacla, esn, tl, tl_xy
from grounding_jax.paper import beyond
from grounding_jax.robot import trained
from grounding_jax.sim import ik, scene, tasks
from grounding_jax.sim import placement as free
from grounding_jax.sim.env import scale_joints


@pytest.fixture(scope="module")
def env():
    return gj.make_env(task_set="free")


def test_the_pointing_map_is_exact_at_its_nodes_and_aims_between_them():
    m = free.pointing_map()
    assert m["joints"].shape == (len(m["x"]), len(m["y"]), 4)
    # it covers the region (and a margin)
    assert m["x"][0] <= free.REACH_X[0] and m["x"][-1] >= free.REACH_X[1]
    assert m["y"][0] <= free.REACH_Y[0] and m["y"][-1] >= free.REACH_Y[1]
    # smooth enough to learn: nodes 1 cm apart differ by < 0.15 scaled L1 (point's success
    # allows 0.1), where the raw searches zigzag by up to 0.84
    scaled = np.asarray(scale_joints(jnp.asarray(m["joints"])))
    for axis in (0, 1):
        assert np.abs(np.diff(scaled, axis=axis)).sum(-1).max() < 0.15
    assert np.abs(np.diff(np.asarray(scale_joints(jnp.asarray(m["raw_joints"]))), axis=1)
                  ).sum(-1).max() > 0.5  # what the smoothing removed
    pose = jax.jit(free.pointing_pose)
    np.testing.assert_allclose(pose(jnp.array([m["x"][3], m["y"][7]])), m["joints"][3, 7],
                               atol=1e-6)
    mid = pose(jnp.array([(m["x"][3] + m["x"][4]) / 2, m["y"][7]]))
    np.testing.assert_allclose(mid, (m["joints"][3, 7] + m["joints"][4, 7]) / 2, atol=1e-6)
    # between nodes the palm still faces the object from 8-15 cm (the slots' definition)
    rng = np.random.default_rng(0)
    for _ in range(20):
        xy = np.array([rng.uniform(*free.REACH_X), rng.uniform(*free.REACH_Y)], np.float32)
        tip, normal = ik.palm_ray(np.asarray(pose(jnp.asarray(xy)), float))
        to_obj = np.array([*xy, scene.TABLE_Z + scene.OBJECT_HALF]) - tip
        dist = np.linalg.norm(to_obj)
        assert np.degrees(np.arccos(to_obj @ normal / dist)) < 3.0
        assert 0.075 < dist < 0.155


@pytest.mark.parametrize("action", ["touch", "push"])
def test_the_touch_and_push_maps_put_the_palm_at_their_point(action):
    """Touch: the palm site 1 cm into the target's top; push: at its near face, 1 cm toward
    the robot from its centre and 0.5 cm above it."""
    m = free.touch_map() if action == "touch" else free.push_map()
    pm = free.pointing_map()
    assert m["joints"].shape == pm["joints"].shape
    np.testing.assert_array_equal(m["x"], pm["x"])
    np.testing.assert_array_equal(m["y"], pm["y"])
    if action == "touch":
        off = np.array([0.0, 0.0, scene.OBJECT_HALF - float(m["depth"])])
    else:
        off = np.asarray(m["offset"], float)
        np.testing.assert_allclose(off, [0.01, 0.0, 0.005], atol=1e-7)
    pose = jax.jit(free.touch_pose if action == "touch" else free.push_pose)
    np.testing.assert_allclose(pose(jnp.array([m["x"][4], m["y"][9]])), m["joints"][4, 9],
                               atol=1e-6)
    # between nodes the palm site lands within a few mm of its point where the arm reaches it
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(40):
        xy = np.array([rng.uniform(*free.REACH_X), rng.uniform(*free.REACH_Y)], np.float32)
        i = int(np.searchsorted(m["x"], xy[0])) - 1
        j = int(np.searchsorted(m["y"], xy[1])) - 1
        if m["reach_error"][i:i + 2, j:j + 2].max() > 1e-3:
            continue
        palm = ik.palm_position(np.asarray(pose(jnp.asarray(xy)), float))
        point = np.array([*xy, scene.TABLE_Z + scene.OBJECT_HALF]) + off
        assert np.linalg.norm(palm - point) < 0.004
        checked += 1
    assert checked >= 20  # most of the region is reached


def test_ik_solve_near_reaches_the_target_or_stays_at_its_prior_by_weight():
    q_true = free.touch_map()["joints"][4, 9].astype(float)
    target = ik.palm_position(q_true)
    prior = q_true + np.array([0.05, -0.05, 0.05, -0.05])
    q, err = ik.solve_near(target, prior, weight=1e-7)
    assert err < 5e-4 and np.linalg.norm(ik.palm_position(q) - target) == pytest.approx(err)
    q, err = ik.solve_near(target, prior, weight=1e3)  # the pull wins: it stays put
    assert np.abs(ik.scaled(q) - ik.scaled(prior)).sum() < 1e-3
    assert err > 5e-3


def test_touch_map_shift_moves_only_unreached_points_and_only_where_it_helps():
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "make_touch_map", scene.ASSETS / "make_touch_map.py")
    mk = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mk)
    m = free.touch_map()
    poses, err = m["joints"].astype(float), np.zeros(m["reach_error"].shape)
    far, near_left = (1, 21), (1, 1)  # (x -0.27, y 0.29): out of reach; (x -0.27, y 0.09): too low
    for ij in (far, near_left):
        err[ij] = m["reach_error"][ij]
    assert err[far] > 0.03 and err[near_left] > 0.01
    off = mk.offset("touch")
    new, new_err, offs = mk.shift_unreached(poses, err, off, most=0.02)
    shift = np.linalg.norm(offs[..., :2] - off[:2], axis=-1)
    # the far-right point moved across the top face, no further than allowed, and is reached
    assert 0 < shift[far] <= 0.02 + 1e-9 and new_err[far] <= mk.SHIFT_FROM
    pressed = mk.centres()[far] + offs[far]
    assert np.linalg.norm(ik.palm_position(new[far]) - pressed) == pytest.approx(new_err[far],
                                                                                 abs=1e-6)
    # the near-left node cannot get down to the top face: no shift halves its error, it stays
    assert shift[near_left] == 0 and np.array_equal(new[near_left], poses[near_left])
    # every other node is untouched
    rest = np.ones(err.shape, bool)
    rest[far] = rest[near_left] = False
    assert np.array_equal(new[rest], poses[rest]) and np.all(shift[rest] == 0)


def test_the_free_actor_is_told_the_targets_coordinates(env):
    n = tasks.POPULATION_GRID[0] * tasks.POPULATION_GRID[1]
    assert tasks.FREE.target_obs == "population"
    assert tasks.FREE.obs_size == 8 + n and env.tasks.obs_target == slice(8, 8 + n)
    code = lambda xy: free.target_units(xy, "population")  # noqa: E731
    placed = free.sample(jax.random.key(2))
    s = env.reset(jax.random.key(0), gj.make_task("touch", "right", 5, "free", placement=placed))
    np.testing.assert_allclose(s.obs[8:], code(placed[2, :2]), atol=1e-6)
    assert np.all((s.obs[8:] > 0) & (s.obs[8:] <= 1.0))
    told = gj.make_task("touch", "right", 5, "free", placement=placed, target_xy=(-0.22, 0.2))
    s = env.reset(jax.random.key(0), told)
    np.testing.assert_allclose(s.obs[8:], code(jnp.array([-0.22, 0.2])), atol=1e-6)
    # the reward still measures the true target: told coordinates change only what it hears
    truth = env.reset(jax.random.key(0), told.replace(target_xy=None))
    assert float(s.metrics["palm_target_dist"]) == float(truth.metrics["palm_target_dist"])
    # point's reward: L1 to the map's pose for where the target stands
    p = env.reset(jax.random.key(0), gj.make_task("point", "right", 5, "free", placement=placed))
    want = jnp.sum(jnp.abs(p.obs[:4] - scale_joints(free.pointing_pose(placed[2, :2]))))
    np.testing.assert_allclose(p.metrics["point_l1"], want, rtol=1e-5)
    # touch's reward: minus the L1 to the touching pose (nothing touched or moved at reset)
    t = env.reset(jax.random.key(0), gj.make_task("touch", "right", 5, "free", placement=placed))
    want = jnp.sum(jnp.abs(t.obs[:4] - scale_joints(free.touch_pose(placed[2, :2]))))
    np.testing.assert_allclose(t.metrics["touch_l1"], want, rtol=1e-5)
    np.testing.assert_allclose(t.reward, -want, rtol=1e-5)
    # push's reward: minus the palm's distance to the target's centre; the pushing pose's
    # L1 (a reward tried, benchmarks/free_tuning.py --push-reward pose) is measured beside it
    u = env.reset(jax.random.key(0), gj.make_task("push", "right", 5, "free", placement=placed))
    want = jnp.sum(jnp.abs(u.obs[:4] - scale_joints(free.push_pose(placed[2, :2]))))
    np.testing.assert_allclose(u.metrics["push_l1"], want, rtol=1e-5)
    assert float(want) > 0.1  # home is far from it
    np.testing.assert_allclose(u.reward, -u.metrics["palm_target_dist"], rtol=1e-6)


def test_the_hand_units_say_where_the_palm_is_relative_to_the_told_target():
    # a length scale other than the shipped one, so the test sees the field used
    hand = tasks.register(tasks.TaskSet("free_hand_test", tasks.FREE.actions,
                                        target_obs="population", hand_obs=True,
                                        hand_scale=0.05))
    assert tasks.FREE_HAND.hand_scale == tasks.HAND_SCALE
    n = tasks.POPULATION_GRID[0] * tasks.POPULATION_GRID[1]
    assert hand.obs_hand == slice(8 + n, 11 + n) and hand.obs_size == tasks.FREE.obs_size + 3
    assert tasks.FREE.obs_hand == slice(8 + n, 8 + n)  # the shipped family has none
    env = gj.make_env(task_set=hand.name)
    placed = free.sample(jax.random.key(2))
    told = gj.make_task("touch", "right", 5, hand.name, placement=placed, target_xy=(-0.22, 0.2))
    s = env.reset(jax.random.key(0), told)
    target_z = scene.TABLE_Z + scene.OBJECT_HALF
    want = lambda st, xy: np.tanh(  # noqa: E731
        (np.asarray(st.info["palm_pos"]) - np.array([*xy, target_z])) / 0.05)
    np.testing.assert_allclose(s.obs[hand.obs_hand], want(s, (-0.22, 0.2)), atol=1e-5)
    np.testing.assert_allclose(s.obs[hand.obs_target], free.target_units(
        jnp.array([-0.22, 0.2]), "population"), atol=1e-6)
    s = jax.jit(env.step)(s, jnp.array([0.5, -0.5, 0.5, 0.5]))  # the palm moves: so do they
    np.testing.assert_allclose(s.obs[hand.obs_hand], want(s, (-0.22, 0.2)), atol=1e-5)
    switched = env.set_task(s, told.replace(target_xy=jnp.array([-0.25, 0.1])))
    np.testing.assert_allclose(switched.obs[hand.obs_hand], want(s, (-0.25, 0.1)), atol=1e-5)
    # a learner sized by the task set takes the longer observation
    agent = cacla.init(jax.random.key(0), cacla.CaclaConfig(task_set=hand.name))
    assert agent.actor.w1.shape[0] == hand.obs_size
    with pytest.raises(ValueError, match="hand_obs: needs the target's table coordinates"):
        tasks.TaskSet("bad_hand", tasks.PAPER.actions, hand_obs=True)
    for bad in (0.0, -0.1, float("nan"), float("inf"), "0.1", True):
        with pytest.raises(ValueError, match="hand_scale: must be a finite number"):
            tasks.TaskSet("bad_hand", tasks.FREE.actions, target_obs="population",
                          hand_obs=True, hand_scale=bad)


def test_a_moving_target_slides_at_its_speed_and_stops_at_the_border(env):
    placed, vel = free.moving(jax.random.key(4), 0.03)
    assert np.all(np.asarray(placed[1:, 0]) == -0.24) and float(placed[1, 1]) >= 0.40
    task = gj.make_task("point", "left", 0, "free", placement=placed, velocity=vel)
    step = jax.jit(env.step)
    s = env.reset(jax.random.key(0), task)
    y0 = float(s.object_start[0, 1])
    idx = scene.index()
    for _ in range(20):
        s = step(s, jnp.zeros(4))
    dt = float(scene.model().opt.timestep) * env.config.substeps
    assert np.isclose(float(s.object_start[0, 1]), y0 + 20 * 0.03 * dt, atol=1e-5)
    assert abs(float(s.qpos[idx.object_qpos[0, 1]]) - float(s.object_start[0, 1])) < 2e-3
    np.testing.assert_allclose(s.obs[8:], free.target_units(s.object_start[0, :2],
                                                            "population"), atol=1e-6)
    fast = s.replace(task=s.task.replace(velocity=jnp.array([0.0, 5.0])))
    fast = step(fast, jnp.zeros(4))
    assert np.isclose(float(fast.object_start[0, 1]), free.REACH_Y[1])  # stopped at the border
    # parked neighbours are accepted only for a moving target
    with pytest.raises(ValueError, match="lies off the reachable region"):
        gj.make_task("point", "left", 0, "free", placement=placed)


def test_the_touch_reward_can_ask_the_arm_to_hold_still_while_it_touches(env):
    placed = free.sample(jax.random.key(2))
    s = env.reset(jax.random.key(0), gj.make_task("touch", "right", 5, "free", placement=placed))
    assert float(s.metrics["arm_moved"]) == 0.0
    s1 = jax.jit(env.step)(s, jnp.array([0.5, -0.5, 0.5, 0.0]))
    moved = jnp.sum(jnp.abs(s1.obs[:4] - s.obs[:4]))  # the scaled joints, before and after
    assert float(moved) > 0.01
    np.testing.assert_allclose(s1.metrics["arm_moved"], moved, rtol=1e-5)
    t = {"touch_l1": 0.2, "touched_target": 1.0, "target_moved": 0.0, "touched_other": 0.0,
         "wrong_moved": False, "arm_moved": 0.3}
    touch = tasks.FREE.actions[tasks.FREE.action_names.index("touch")]

    def reward(terms, **params):
        return float(touch.reward(terms, gj.EnvParams(**params)))

    assert reward(t) == pytest.approx(-0.2)  # off by default
    assert reward(t, touch_still_penalty=2.0) == pytest.approx(-0.2 - 2.0 * 0.3)
    # only while touching: an arm moving in the air pays nothing
    assert reward({**t, "touched_target": 0.0}, touch_still_penalty=2.0) == pytest.approx(-0.2)
    with pytest.raises(ValueError, match="touch_still_penalty: must be >= 0, got -1"):
        gj.EnvParams(touch_still_penalty=-1.0).validate()


def test_bad_free_settings_are_refused_by_name():
    with pytest.raises(ValueError, match="placement: unknown value 'anywhere'"):
        al.ALConfig(placement="anywhere")
    with pytest.raises(ValueError, match="target_obs: unknown value 'polar'"):
        tasks.TaskSet("polar", tasks.PAPER.actions, target_obs="polar")
    with pytest.raises(ValueError, match="'free' is built in"):
        tasks.register(tasks.TaskSet("free", tasks.PAPER.actions))
    with pytest.raises(ValueError, match="placement: these modules hold no free-family robot"):
        trained.Robot(None, None, None, gj.EnvConfig(), {}).perform("push", "red",
                                                                   placement="random")


def test_training_draws_a_placement_per_episode():
    cfg = beyond.config(0, 3)
    parts = al._Parts(cfg)
    a, _, _ = parts.draw(jax.random.key(0))
    b, _, _ = parts.draw(jax.random.key(1))
    free.check(np.stack([a.placement, b.placement]))
    assert not np.array_equal(a.placement, b.placement)
    paper = al._Parts(al.ALConfig(phase1_episodes=0, phase2_episodes=3)).draw(jax.random.key(0))
    assert paper[0].placement is None and int(paper[0].action) == int(a.action)


def test_the_robot_saved_with_its_free_family_looks_then_acts(tmp_path, renderer):
    k = jax.random.key(0)
    xy_cfg = tl_xy.XYConfig(hidden=8, replication=2)
    # two trained agents saved beside the robot's own (the second)
    agents = jax.vmap(lambda kk: cacla.init(kk, beyond.FREE_LEARNER))(jax.random.split(k, 2))
    free_agent = jax.tree.map(lambda x: x[1], agents)
    xy_params = tl_xy.init(k, xy_cfg)
    # an untrained namer of the right shape (train.py's quick profile trains a real one:
    # tests/test_train.py checks that it fits its sequences)
    esn_cfg = esn.ESNConfig(n_in=40 + xy_cfg.hidden, task_set="free")
    net = esn.init(k, esn_cfg)
    modules = {"xy_params": xy_params, "xy_config": xy_cfg, "agent": free_agent,
               "al_config": beyond.FREE_LEARNER,
               "env_config": beyond.env_config(), "net": net, "esn_config": esn_cfg,
               "params": beyond.params(), "agents": agents, "saved_agent": 1}
    tl_cfg = tl.TLConfig(max_hidden=5, max_replication=1)
    tl_hp = tl.TLHyper(hidden=5, replication=1)
    trained.save(tmp_path / "m", tl.init(k, tl_hp, tl_cfg), tl_hp,
                 cacla.init(k, cacla.CaclaConfig()), cacla.CaclaConfig(),
                 esn.init(k), esn.ESNConfig(), gj.EnvConfig(), free_modules=modules)
    robot = gj.load(tmp_path / "m")
    assert robot.free is not None and robot.free.xy_config == xy_cfg
    for a, b in zip(jax.tree.leaves((robot.free.al.agent, robot.free.xy_params)),
                    jax.tree.leaves((modules["agent"], modules["xy_params"])), strict=True):
        np.testing.assert_array_equal(a, b)
    out = robot.perform("push", "red", 4, steps=3, placement="random", key=jax.random.key(5))
    assert out["trajectory"].reward.shape == (3,) and out["xy"].shape == (2,)
    assert out["image"].ndim == 3
    assert out["named"][0] in tasks.FREE.action_names and out["named"][1] in tasks.TARGET_WORDS
    np.testing.assert_array_equal(robot.free.an.net.w_out, net.w_out)
    placed = np.asarray(out["placement"])
    free.check(placed)
    np.testing.assert_array_equal(out["true_xy"], placed[scene.POSITIONS.index(
        out["true_position"]), :2])
    # what the actor heard is the TL's estimate, not the truth: its coordinates and, in the
    # hand units, where the palm is relative to them
    ts = tasks.get(robot.free.env_config.task_set)
    assert ts is tasks.FREE_HAND
    first = out["trajectory"]
    np.testing.assert_allclose(first.obs[0, ts.obs_target],
                               free.target_units(out["xy"], "population"), atol=1e-5)
    told = np.array([*out["xy"], scene.TABLE_Z + scene.OBJECT_HALF])
    np.testing.assert_allclose(first.obs[0, ts.obs_hand], np.tanh(
        (np.asarray(first.info["palm_pos"][0]) - told) / tasks.HAND_SCALE), atol=1e-5)
    # it acts with the env parameters it was trained with (the free family's action scale)
    assert float(robot.free.params.action_scale) == beyond.FREE_TUNED["action_scale"] != 1 / 3
    same = robot.perform("push", "red", 4, steps=3, placement="random", key=jax.random.key(5),
                         params=beyond.params())
    paper = robot.perform("push", "red", 4, steps=3, placement="random", key=jax.random.key(5),
                          params=gj.EnvParams())
    np.testing.assert_array_equal(out["trajectory"].qpos, same["trajectory"].qpos)
    assert not np.array_equal(out["trajectory"].qpos, paper["trajectory"].qpos)
    # every saved agent can act in its place; the compiled episode is shared
    assert robot.free.n_agents == 2 and robot.free.saved_agent == 1
    first = robot.with_free_agent(0)
    np.testing.assert_array_equal(first.free.al.agent.actor.w1, agents.actor.w1[0])
    assert first._performers.keys() == robot._performers.keys()
    other = first.perform("push", "red", 4, steps=3, placement="random", key=jax.random.key(5))
    again = robot.with_free_agent(1).perform("push", "red", 4, steps=3, placement="random",
                                             key=jax.random.key(5))
    np.testing.assert_array_equal(again["trajectory"].qpos, out["trajectory"].qpos)
    assert not np.array_equal(other["trajectory"].qpos, out["trajectory"].qpos)
    for bad in (2, -1, 0.5, True):
        with pytest.raises(ValueError, match=r"i: .*0\.\.1"):
            robot.with_free_agent(bad)
    # a config whose saved agent is not among the saved ones is refused before restoring:
    # edited into config.json (its checksum no longer matches), and by the config check
    cfg_path = tmp_path / "m" / "config.json"
    cfg = json.loads(cfg_path.read_text())
    cfg["config"]["free"]["saved_agent"] = 2
    cfg_path.write_text(json.dumps(cfg))
    with pytest.raises(CheckpointError, match="config.json: edited after step 0"):
        gj.load(tmp_path / "m")
    with pytest.raises(CheckpointError, match="saved_agent"):
        trained._configs(cfg["config"])


def test_the_saved_agent_is_the_one_that_clears_every_goal_by_most():
    table = {"per_agent_by_action": {"point": [1.0, 0.95, 0.91, 0.99],
                                     "touch": [0.95, 0.84, 0.95, 0.84],
                                     "push": [0.80, 0.92, 0.99, 0.92]},
             "per_agent": [0.92, 0.90, 0.95, 0.92]}
    # worst margins: push -0.05; touch +0.04; point +0.01; touch +0.04 (the higher overall)
    assert beyond.choose(table) == 3
    table["per_agent"][1] = 0.93
    assert beyond.choose(table) == 1


def test_a_sweep_trains_the_free_family_and_judges_it_on_held_out_placements(tmp_path,
                                                                             monkeypatch):
    from grounding_jax import sweep
    from grounding_jax.paper import al_eval

    monkeypatch.setattr(al_eval, "FREE_EVAL_PLACEMENTS", 1)  # 9 + 3 episodes per agent
    spec = sweep.parse_spec({
        "module": "al", "name": "free_tiny", "seeds": 2, "chunk": 2, "metric": "success_mean",
        "params": {"phase1_episodes": 1, "phase2_episodes": 1, "actor_hidden": 4,
                   "critic_hidden": 4, "episode_length": 5, "placement": "random"},
        "grid": {"gamma": [0.0, 0.3]}})
    cfg = sweep.module_config(spec, spec.groups()[0][0])
    assert cfg.placement == "random"
    assert cfg.env.task_set == cfg.learner.task_set == beyond.FREE_LEARNER.task_set
    assert cfg.learner.heads == beyond.FREE_LEARNER.heads  # the free family's networks
    sweep.run(spec, tmp_path, show_progress=False)
    with np.load(tmp_path / "free_tiny" / "metrics.npz") as f:
        rates = f["success_point"]
    assert rates.shape == (4, 1) and np.all((rates >= 0) & (rates <= 1))
    (_, agents, _), _ = sweep.trained_agents(spec, tmp_path)
    # the first point's 2 agents, each with a network slot per action
    ts = tasks.get(beyond.FREE_LEARNER.task_set)
    assert agents.actor.w1.shape == (2, ts.n_actions, ts.obs_size, 4)
    with pytest.raises(sweep.SweepError, match="placement"):
        sweep.parse_spec({"module": "al", "params": {"placement": "anywhere"},
                          "grid": {"gamma": [0.0]}})


def test_the_population_code_peaks_at_its_centres_and_fills_the_observation():
    grid = tasks.POPULATION_GRID
    corner = jnp.array([free.REACH_X[0], free.REACH_Y[0]])
    code = np.asarray(free.population(corner, grid))
    assert code.shape == (grid[0] * grid[1],) and code[0] == 1.0 and np.all(code > 0)
    # one grid spacing along y from the corner: the next centre is at exp(-1/2) there
    np.testing.assert_allclose(code[1], np.exp(-0.5), rtol=1e-6)
    ts = tasks.register(tasks.TaskSet("test_population", tasks.FREE.actions,
                                      target_obs="population"))
    assert ts.obs_size == 8 + grid[0] * grid[1]
    env = gj.make_env(task_set=ts.name)
    placed = free.sample(jax.random.key(3))
    s = env.reset(jax.random.key(0), gj.make_task("push", "middle", 2, ts.name,
                                                  placement=placed))
    np.testing.assert_allclose(s.obs[8:], free.population(placed[1, :2], grid), atol=1e-6)
    with pytest.raises(ValueError, match="target_obs: 'position' has no coordinates"):
        free.target_units(placed[1, :2], "position")
