"""Trained modules, saved together and loaded ready to use: ``grounding_jax.load(path)``.

``train.py`` saves the TL, one AL agent and one AN (ESN with its readout) to
``results/<profile>/modules``. `load` returns a `Robot`::

    robot = grounding_jax.load("results/paper/modules")
    robot.tl.localize(layout=3, word="red")        # where the red object lies: 0 L, 1 M, 2 R
    robot.al.act(obs)                              # the greedy actor's move for an observation
    out = robot.perform("push", "red", layout=3)   # find it, do it, name it
    out["named"]                                   # ("push", "red")
    out = robot.perform("push", "red", layout=3, placement="random", key=jax.random.key(1))
    out["xy"], out["true_xy"]                      # the continuous TL's estimate, the truth
    robot.watch(robot.with_agent(2).perform("touch", "green", layout=7))   # names what
                                                   # another agent did ("touch", "green")

With ``placement`` (objects anywhere; needs the modules of the free family, which
``train.py`` saves beside the paper's) the robot renders the scene with its eye camera, the
continuous TL (`grounding_jax.learn.tl_xy`) reads the target's coordinates from it, and the
free family's actor acts on them, and the free family's namer (an ESN over that actor's and
that TL's hidden layers) names what was done (``named`` is None for modules saved without it).

`Robot.watch` names an episode the robot only watched, by motor resonance through its
own actor (`grounding_jax.robot.observer`); ``agents`` holds the other AL agents trained
beside its own (`Robot.with_agent`).

A checkpoint is refused (`CheckpointError`) when it was written by another package
version, when its config.json was edited after saving, when a file or an array differs from
the checksums saved with it, when its config is not one this version can build, or when its
arrays do not match that config. `save` holds the parent folder's writer lock and
replaces an earlier save only once the new one is complete.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import shutil
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core import guard, trees, xla
from grounding_jax.core.checkpoint import Checkpointer, CheckpointError, read_config
from grounding_jax.learn import al, cacla, esn, learners, tl, tl_xy
from grounding_jax.robot import observer, seeing
from grounding_jax.sim import scene, tasks, tl_data
from grounding_jax.sim.env import DEFAULT_PARAMS, Env, EnvConfig, EnvParams, State, make_task

KIND = "modules"


@dataclasses.dataclass(frozen=True)
class TrainedTL:
    """The target localizer: where does the named object lie?"""

    params: tl.TLParams
    hyper: tl.TLHyper  # hidden size, replication n and input scales it was trained with

    def _inputs(self, bitmap: jax.Array, symbols: jax.Array) -> tuple[jax.Array, jax.Array]:
        cfg = tl.TLConfig(max_hidden=self.params.w1.shape[1],
                          max_replication=(self.params.w1.shape[0] - tl.N_PIXELS)
                          // tl.N_SYMBOLS)
        hp = self.hyper
        lead = jnp.shape(bitmap)[:-1]
        x = tl.build_inputs(jnp.reshape(bitmap, (-1, tl.N_PIXELS)),
                            jnp.reshape(symbols, (-1, tl.N_SYMBOLS)), hp, cfg)
        return x.reshape(*lead, -1), tl.masks(hp, cfg)[1]

    def hidden_layer(self, bitmap: jax.Array, symbols: jax.Array) -> jax.Array:
        """Hidden activations ``[..., max_hidden]`` (units past ``hidden`` are 0), the AN's
        "what" input."""
        x, mask = self._inputs(bitmap, symbols)
        return tl.apply(self.params, x, mask)[0]

    def outputs(self, bitmap: jax.Array, symbols: jax.Array) -> jax.Array:
        """The three position outputs ``[..., 3]`` (in (0, 1); the position is their
        argmax)."""
        x, mask = self._inputs(bitmap, symbols)
        return tl.apply(self.params, x, mask)[1]

    def position(self, bitmap: jax.Array, symbols: jax.Array) -> jax.Array:
        """Position index (0 left, 1 middle, 2 right) for bitmaps ``[..., 1200]`` and symbol
        units ``[..., 15]`` (see `tl_data.symbol_units`)."""
        return jnp.argmax(self.outputs(bitmap, symbols), axis=-1)

    def localize(self, layout: int, word: str) -> int:
        """Position of the object ``word`` ("box", "red", ...) names in scene ``layout``, from
        the layout's cached camera bitmap."""
        bitmap, symbols = _configuration(layout, word)
        return int(self.position(bitmap, symbols))


@dataclasses.dataclass(frozen=True)
class TrainedAL:
    """The action learner's actor (and critic)."""

    agent: cacla.Agent
    config: cacla.CaclaConfig

    def act(self, obs: jax.Array) -> jax.Array:
        """The greedy action (no exploration) for observations ``[..., 11]``."""
        return learners.for_config(self.config).policy(self.agent, obs)[0]

    def hidden_layer(self, obs: jax.Array) -> jax.Array:
        """The policy's hidden features (the AN's "how" input)."""
        return learners.for_config(self.config).policy(self.agent, obs)[1]

    def value(self, obs: jax.Array) -> jax.Array:
        """The critic's value of an observation ``[11]`` (CACLA's critic)."""
        return cacla.critic_apply(self.agent.critic, obs)


@dataclasses.dataclass(frozen=True)
class TrainedAN:
    """The action namer: an ESN over [actor hidden, TL hidden] sequences."""

    net: esn.ESN
    config: esn.ESNConfig = esn.ESNConfig()

    def outputs(self, actor_hidden: jax.Array, tl_hidden: jax.Array) -> jax.Array:
        """The 9 outputs at each step for a sequence ``[T, actor hidden]`` and the TL's
        hidden layer ``[tl hidden]`` (held over the sequence); zero initial state."""
        tl_part = jnp.broadcast_to(tl_hidden, actor_hidden.shape[:1] + tl_hidden.shape)
        states = esn.run(self.net, jnp.concatenate([actor_hidden, tl_part], axis=1))
        return esn.apply(self.net, states)

    def name(self, actor_hidden: jax.Array, tl_hidden: jax.Array) -> tuple[str, str]:
        """(action word, target word) at the sequence's last step."""
        return _words(self.outputs(actor_hidden, tl_hidden)[-1], self.config)


@dataclasses.dataclass(frozen=True)
class TrainedFree:
    """The free family's modules: the continuous TL, an actor told the target's (x, y), and
    (when trained) a namer over the two's hidden layers. ``params``: the env parameters the
    actor was trained with (its action scale), which it acts with. ``agents``: every agent
    trained beside it (stacked, when saved), ``saved_agent`` the index of ``al``'s among them
    (see `Robot.with_free_agent`)."""

    xy_params: tl_xy.XYParams
    xy_config: tl_xy.XYConfig
    al: TrainedAL
    env_config: EnvConfig
    an: TrainedAN | None = None
    params: EnvParams = DEFAULT_PARAMS
    agents: cacla.Agent | None = None
    saved_agent: int | None = None

    @property
    def n_agents(self) -> int:
        """How many trained agents ``agents`` holds (0 when none were saved)."""
        return _count(self.agents)

    def _inputs(self, rgb: np.ndarray, layout: int, word: str) -> tuple[jax.Array, jax.Array]:
        w = tl_data.word_index(word)
        return (jnp.asarray(tl_xy.bitmap(rgb)), jnp.asarray(tl_xy.SYMBOLS[int(layout), w]))

    def localize(self, rgb: np.ndarray, layout: int, word: str) -> np.ndarray:
        """The target's table coordinates (metres, ``[2]``) from an eye-camera image of
        scene ``layout``, for the object ``word`` names."""
        return np.asarray(tl_xy.localize(self.xy_params, *self._inputs(rgb, layout, word),
                                         self.xy_config))

    def tl_hidden(self, rgb: np.ndarray, layout: int, word: str) -> jax.Array:
        """The continuous TL's hidden layer for that image and word (the namer's "what")."""
        return tl_xy.hidden(self.xy_params, *self._inputs(rgb, layout, word), self.xy_config)


def _spoken(w: Any) -> Any:
    """A command's word as heard: case and surrounding spaces do not matter (" RED " is
    "red"); anything but a string is left for the checks to refuse."""
    return w.strip().lower() if isinstance(w, str) else w


@dataclasses.dataclass(frozen=True)
class Robot:
    """The three trained modules together, as `load` returns them (``free``: the free
    family's modules when the checkpoint has them, else None; ``agents``: every AL agent
    trained beside the robot's own, stacked, when saved -- ``saved_agent`` is the index of
    ``al``'s among them; see `with_agent`)."""

    tl: TrainedTL
    al: TrainedAL
    an: TrainedAN
    env_config: EnvConfig
    config: dict[str, Any]
    free: TrainedFree | None = None
    agents: cacla.Agent | None = None
    saved_agent: int | None = None
    frames_namers: dict[str, seeing.FramesNamer] | None = None
    # perform's compiled episode, one per step count (filled on first use)
    _performers: dict[Any, Callable] = dataclasses.field(
        default_factory=dict, init=False, repr=False, compare=False)

    @property
    def n_agents(self) -> int:
        """How many paper-family AL agents ``agents`` holds (0 when none were saved)."""
        return _count(self.agents)

    def with_agent(self, i: int) -> Robot:
        """This robot acting with the paper family's trained AL agent ``i`` (of ``agents``:
        all that train.py trained, from different seeds; by default it acts with
        ``saved_agent``). The TL and the AN stay its own; the compiled episodes are shared.
        The AN was fitted on the saved agent's hidden layer, so ``perform``'s ``named`` is not
        to be trusted for another agent; the robot's `watch` names what it did.

        Raises:
            ValueError: no agents saved, or ``i`` out of range.
        """
        agent = trees.take(self.agents, _agent_index(i, self.n_agents, ""))
        robot = dataclasses.replace(self, al=TrainedAL(agent, self.al.config))
        robot._performers.update(self._performers)
        return robot

    def with_free_agent(self, i: int) -> Robot:
        """This robot acting with the free family's trained agent ``i`` (of
        ``free.agents``: all that train.py trained; by default the robot acts with
        ``free.saved_agent``). The compiled episodes are shared: the agent is an argument.

        Raises:
            ValueError: no free-family agents saved, or ``i`` out of range.
        """
        n = 0 if self.free is None else self.free.n_agents
        agent = trees.take(self.free.agents, _agent_index(i, n, "free-family "))
        free = dataclasses.replace(self.free, al=TrainedAL(agent, self.free.al.config))
        robot = dataclasses.replace(self, free=free)
        robot._performers.update(self._performers)
        return robot

    def _performer(self, steps: int) -> Callable:
        if steps not in self._performers:
            evaluate = al.make_eval(self.env_config, steps)

            # the modules' arrays are arguments, not constants baked into the compile
            def run(agent, tl_params, net, key, task, params, bitmap, symbols):
                _, traj, hidden = evaluate(agent, key, task, params)
                tl_h = TrainedTL(tl_params, self.tl.hyper).hidden_layer(bitmap, symbols)
                return traj, TrainedAN(net).outputs(hidden, tl_h)[-1]

            self._performers[steps] = xla.physics_jit(run, self.env_config.backend)
        return self._performers[steps]

    def perform(self, action: str, word: str, layout: int = 0, steps: int = 100,
                key: jax.Array | None = None, params: EnvParams | None = None,
                placement: Any = None) -> dict:
        """Hear "<action> <word>" in scene ``layout``: the TL finds the object, the actor
        does the action for ``steps`` steps, the AN names what was done.

        The episode is compiled on the first call for a step count; later calls reuse it.

        Args:
            action: the command's action ("push"; case and surrounding spaces do not
                matter).
            word: the command's target word ("red", " RED " alike).
            layout: which shape and colour stands in each slot (0..35).
            steps: RL steps to act.
            key: PRNG key (the reset's; with ``placement="random"`` split once: placement,
                reset).
            params: env parameters (default: those the acting robot was trained with --
                ``EnvParams()`` for the paper's, ``free.params`` with a placement).
            placement: None (the paper's slots), ``"random"`` or coordinates ``[3, 2|3]``
                (see `make_task`): objects anywhere, seen through the eye camera
                (needs ``self.free``).

        Returns:
            ``position`` (the TL's answer), ``true_position``, ``final_reward``,
            ``trajectory`` (env states after each step) and ``named`` (action, target word);
            with a placement also ``xy`` (the continuous TL's estimate, metres),
            ``true_xy``, ``placement`` and ``image`` (the camera frame it saw).
        """
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ValueError(f"steps: {steps!r} is not accepted; accepted: an int >= 1")
        action, word = _spoken(action), _spoken(word)
        if params is not None:
            params.validate()  # on the host: inside the compiled episode it is traced
        if placement is not None:
            return self._perform_free(action, word, layout, steps, key, params, placement)
        params = DEFAULT_PARAMS if params is None else params
        bitmap, symbols = _configuration(layout, word)  # read once: localize and name use it
        position = int(self.tl.position(bitmap, symbols))
        task = make_task(action, position, layout, self.env_config.task_set)
        key = jax.random.key(0) if key is None else key
        traj, named = self._performer(steps)(self.al.agent, self.tl.params, self.an.net, key,
                                             task, params, bitmap, symbols)
        return {"position": scene.POSITIONS[position],
                "true_position": scene.POSITIONS[tl_data.label_of(layout,
                                                                  tl_data.word_index(word))],
                "final_reward": float(traj.reward[-1]), "trajectory": traj,
                "named": _words(named, self.an.config)}


    def _perform_free(self, action: str, word: str, layout: int, steps: int,
                      key: jax.Array | None, params: EnvParams | None, placement: Any
                      ) -> dict:
        from grounding_jax.sim import vision

        if self.free is None:
            raise ValueError("placement: these modules hold no free-family robot (train.py "
                             "saves one); accepted: None")
        key = jax.random.key(0) if key is None else key
        params = self.free.params if params is None else params
        k_place, k_reset = jax.random.split(key)
        cfg = self.free.env_config
        task = make_task(action, word, layout, cfg.task_set, placement=placement, key=k_place)
        placed = np.asarray(task.placement)
        image = vision.eye_renderer().render(int(task.layout), placed)
        xy = self.free.localize(image, int(task.layout), word)
        task = task.replace(target_xy=jnp.asarray(xy, jnp.float32))
        if ("free", steps) not in self._performers:
            self._performers[("free", steps)] = xla.physics_jit(al.make_eval(cfg, steps),
                                                                cfg.backend)
        _, traj, hidden = self._performers[("free", steps)](self.free.al.agent, k_reset, task,
                                                            params)
        named = None
        if self.free.an is not None:
            named = self.free.an.name(hidden, self.free.tl_hidden(image, int(task.layout), word))
        slot = int(task.position)
        return {"position": scene.POSITIONS[slot], "true_position": scene.POSITIONS[slot],
                "xy": xy, "true_xy": placed[slot, :2], "placement": placed, "image": image,
                "final_reward": float(traj.reward[-1]), "trajectory": traj, "named": named}


    # ----------------------------------------------------------------------- watching
    def _watch_family(self, states) -> tuple[bool, Any]:
        """(free family?, the watched states checked) for a trajectory."""
        if isinstance(states, dict) and "trajectory" in states:
            states = states["trajectory"]
        free = isinstance(states, State) and states.task.placement is not None
        if free and self.free is None:
            raise ValueError("trajectory: an episode with objects placed anywhere, and these "
                             "modules hold no free-family robot to watch it with; accepted: "
                             "episodes on the paper's slots")
        size = (self.free.env_config if free else self.env_config).tasks.obs_size
        return free, observer.check_states(states, size)

    def _resonator(self, free: bool) -> Callable:
        """The jitted watching of a batch of episodes of a family: the resonance, the word for
        the chosen slot and the AN's outputs (the modules' arrays are arguments)."""
        if ("watch", free) in self._performers:
            return self._performers[("watch", free)]
        cfg = self.free.env_config if free else self.env_config
        env = Env(cfg)
        lrn = learners.for_config((self.free.al if free else self.al).config)
        resonance = observer.make_resonance(env, lrn)

        def command(agent, states, params):
            err = resonance(agent, states, params)
            score = observer.score(err)
            a, p = observer.best(score)
            return (err, score), a, p, observer.hidden_under(env, lrn, agent, states, a, p)

        if free:
            xy_config, has_an = self.free.xy_config, self.free.an is not None

            def run(agent, xy_params, net, states, params, bitmap):
                err, a, p, hidden = command(agent, states, params)
                words = jnp.asarray(tl_xy.SYMBOLS)[states.task.layout[0]]
                bitmaps = jnp.broadcast_to(bitmap, (words.shape[0], bitmap.shape[0]))
                estimates = tl_xy.localize(xy_params, bitmaps, words, xy_config)
                w = observer.free_word(estimates, states.task.placement[0, p, :2])
                out = (TrainedAN(net).outputs(hidden, tl_xy.hidden(
                    xy_params, bitmap, words[w], xy_config))[-1] if has_an else jnp.zeros(()))
                return err, a, p, w, out

            fn = jax.vmap(run, in_axes=(None, None, None, 0, None, 0))
        else:
            hyper = self.tl.hyper

            def run(agent, tl_params, net, states, params):
                err, a, p, hidden = command(agent, states, params)
                # constants of the program (converted while tracing: no program of their own)
                bitmaps = jnp.asarray(tl_data.cached_bitmaps(), jnp.float32)
                symbols = jnp.asarray(tl_xy.SYMBOLS)
                layout = states.task.layout[0]
                trained_tl = TrainedTL(tl_params, hyper)
                words = symbols[layout]
                probs = trained_tl.outputs(
                    jnp.broadcast_to(bitmaps[layout], (words.shape[0], bitmaps.shape[1])), words)
                w = observer.paper_word(probs, p)
                tl_h = trained_tl.hidden_layer(bitmaps[layout], words[w])
                return err, a, p, w, TrainedAN(net).outputs(hidden, tl_h)[-1]

            fn = jax.vmap(run, in_axes=(None, None, None, 0, None))
        self._performers[("watch", free)] = xla.physics_jit(fn, self.env_config.backend)
        return self._performers[("watch", free)]

    def resonance(self, trajectory: Any, params: EnvParams | None = None) -> dict | list[dict]:
        """Which of its own commands explains a watched episode best (motor resonance, see
        `grounding_jax.robot.observer`), and how it names it.

        Args:
            trajectory: env states after each step, stacked ``[T, ...]`` (``T >= 2``) -- as
                `perform` returns in ``"trajectory"`` (its output dict is accepted too),
                or any env trajectory of another robot -- or a batch ``[N, T, ...]``. An
                episode with a placement is watched with the free family's modules (and its
                scene seen through the eye camera).
            params: the observer's env parameters for its imagined moves (default: those its
                actor was trained with).

        Returns:
            ``action`` and ``position`` (the command it resonates with), ``errors`` (``[2, 3
            actions, 3 slots]``: the joint and the hand mismatch of each command), ``score``
            (``[3, 3]``, the resonance score: smaller explains better), ``named`` (action
            word, target word; None for a free-family episode when the modules hold no
            free-family namer), ``word`` (the target word it chose); a list of these for a
            batch.

        Raises:
            ValueError: not a trajectory of env states, of the wrong observation size, fewer
                than 2 steps, or an episode with a placement for modules without the free
                family.
        """
        free, states = self._watch_family(trajectory)
        if params is not None:
            params.validate()
        batched = np.ndim(states.obs) == 3
        many = states if batched else trees.add_axis(states)
        if free:
            from grounding_jax.sim import vision

            params = self.free.params if params is None else params
            layouts = np.asarray(many.task.layout)[:, 0]
            placed = np.asarray(many.task.placement)[:, 0]
            renderer = vision.eye_renderer()
            bitmaps = np.stack([tl_xy.bitmap(renderer.render(int(lay), pl))
                                for lay, pl in zip(layouts, placed, strict=True)])
            out = self._resonator(True)(self.free.al.agent, self.free.xy_params,
                                        self.free.an.net if self.free.an else None, many,
                                        params, jnp.asarray(bitmaps, jnp.float32))
            an_config = self.free.an.config if self.free.an else None
            names = self.free.env_config.tasks.action_names
        else:
            params = DEFAULT_PARAMS if params is None else params
            out = self._resonator(False)(self.al.agent, self.tl.params, self.an.net, many,
                                         params)
            an_config, names = self.an.config, self.env_config.tasks.action_names
        (err, score), a, p, w, outputs = jax.device_get(out)
        rows = [{"action": names[int(a[i])], "position": scene.POSITIONS[int(p[i])],
                 "errors": err[i], "score": score[i],
                 "word": tl_data.TARGET_WORDS[int(w[i])],
                 "named": _words(outputs[i], an_config) if an_config else None}
                for i in range(len(a))]
        return rows if batched else rows[0]

    def watch(self, trajectory: Any, params: EnvParams | None = None
              ) -> tuple[str, str] | None | list:
        """Name an action it only watched: (action word, target word), as `perform`'s
        ``named`` -- the command it resonates with, named by its AN (see `resonance`;
        None for a free-family episode when the modules hold no free-family namer). A batch
        ``[N, T, ...]`` gives a list.

        Raises:
            ValueError: see `resonance`.
        """
        out = self.resonance(trajectory, params)
        return [r["named"] for r in out] if isinstance(out, list) else out["named"]

    def watch_frames(self, frames: Any, family: str = "paper", camera: str = "observer"
                     ) -> tuple[str, str] | list:
        """Name an action from rendered frames only -- ``grounding_jax.frames(episode)``,
        ``uint8 [T, H, W, 3]``, or a batch ``[N, T, H, W, 3]`` -- with no joint angles and no
        simulator state (see `grounding_jax.robot.seeing`): (action word, the target's colour
        word), a list for a batch. ``family``: whose frames ("paper": objects on the slots,
        "free": objects anywhere); ``camera``: the one they were rendered from, the namer's
        (``"both"``: ``grounding_jax.frames(episode, camera="both")``, the observer's and the
        eye's views side by side).

        Raises:
            ValueError: frames of another shape or type, an unknown family, a camera other
                than its namer's, or modules saved without a frames namer for it (the
                ``watch_frames`` stage fits one and saves the robot with it).
        """
        names = (self.free.env_config if family == "free" and self.free
                 else self.env_config).tasks.action_names
        return seeing.watch(self.frames_namers, frames, family, names, camera)


def _count(agents: Any) -> int:
    return 0 if agents is None else int(jax.tree.leaves(agents)[0].shape[0])


def _agent_index(i: Any, n: int, family: str) -> int:
    """``i`` checked as an index among ``n`` saved agents (ValueError naming ``i``)."""
    if n == 0:
        raise ValueError(f"i: these modules hold no saved {family}agents (train.py saves them "
                         "beside the robot's own)")
    if isinstance(i, bool) or not isinstance(i, int | np.integer) or not 0 <= int(i) < n:
        raise ValueError(f"i: agent index {i!r} out of range; accepted: 0..{n - 1}")
    return int(i)


def _check_agents(entry: Any, field: str) -> None:
    n, i = entry["n_agents"], entry["saved_agent"]
    if not (type(n) is int and n >= 1 and type(i) is int and 0 <= i < n):
        raise ValueError(f"{field}: n_agents must be an integer >= 1 and saved_agent one of "
                         f"0..n_agents - 1, got {n!r} and {i!r}")


def _stacked_like(config: cacla.CaclaConfig, n: int, k: jax.Array):
    return jax.eval_shape(lambda: jax.vmap(lambda kk: cacla.init(kk, config))(
        jax.random.split(k, n)))


def _params_json(params: EnvParams) -> dict[str, float | int]:
    """Env parameters as JSON numbers (for config.json)."""
    return {f.name: np.asarray(getattr(params, f.name)).item()
            for f in dataclasses.fields(params)}


def _words(outputs: jax.Array, config: esn.ESNConfig) -> tuple[str, str]:
    """(action word, target word) of the AN's outputs at one step."""
    names = tasks.get(config.task_set).action_names
    a, w = esn.decode(outputs, len(names))
    return names[int(a)], tl_data.TARGET_WORDS[int(w)]


def _configuration(layout: int, word: str) -> tuple[jax.Array, jax.Array]:
    if not 0 <= int(layout) < len(scene.LAYOUTS):
        raise ValueError(f"layout: index {layout} out of range; accepted: 0..35")
    return (jnp.asarray(tl_data.cached_bitmaps()[int(layout)], jnp.float32),
            jnp.asarray(tl_data.symbol_units(int(layout), word)))


def _configs(config: dict) -> tuple[tl.TLConfig, tl.TLHyper, cacla.CaclaConfig, esn.ESNConfig,
                                    EnvConfig]:
    """The module configs a checkpoint's config.json describes (CheckpointError if not)."""
    try:
        if "free" in config:  # checked here so that a bad one is refused before restoring
            f = config["free"]
            tl_xy.XYConfig(**f["xy"]), cacla.CaclaConfig(**f["al"]), EnvConfig(**f["env"])
            EnvParams(**f.get("params", {})).validate()
            if "an" in f:
                esn.ESNConfig(**f["an"])
            if "n_agents" in f:
                _check_agents(f, "free")
        if "al_agents" in config:
            _check_agents(config["al_agents"], "al_agents")
        if "frames" in config:
            seeing.namers_like(config["frames"])
        t = config["tl"]
        tl_cfg = tl.TLConfig(max_hidden=t["max_hidden"], max_replication=t["max_replication"])
        # input scales: 1 (the paper's) in configs written before they existed
        tl_hp = tl.TLHyper(hidden=t["hidden"], replication=t["replication"],
                           image_scale=t.get("image_scale", 1.0),
                           target_scale=t.get("target_scale", 1.0))
        tl.validate(tl_hp, tl_cfg)
        return (tl_cfg, tl_hp, cacla.CaclaConfig(**config["al"]), esn.ESNConfig(**config["an"]),
                EnvConfig(**config["env"]))
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"config.json: not a valid modules config ({type(e).__name__}: "
                              f"{e})") from e


def _like(config: dict):
    tl_cfg, tl_hp, al_cfg, esn_cfg, _ = _configs(config)
    k = jax.random.key(0)
    like = {}
    if "free" in config:
        f = config["free"]
        like["free"] = {
            "xy": jax.eval_shape(lambda: tl_xy.init(k, tl_xy.XYConfig(**f["xy"]))),
            "al": jax.eval_shape(lambda: cacla.init(k, cacla.CaclaConfig(**f["al"])))}
        if "n_agents" in f:
            like["free"]["agents"] = _stacked_like(cacla.CaclaConfig(**f["al"]), f["n_agents"], k)
        if "an" in f:
            like["free"]["an"] = _esn_like(esn.ESNConfig(**f["an"]))
    if "al_agents" in config:
        like["al_agents"] = _stacked_like(al_cfg, config["al_agents"]["n_agents"], k)
    if "frames" in config:
        like["frames"] = seeing.namers_like(config["frames"])
    return like | {"tl": jax.eval_shape(lambda: tl.init(k, tl_hp, tl_cfg)),
                   "al": jax.eval_shape(lambda: cacla.init(k, al_cfg)),
                   "an": _esn_like(esn_cfg)}


def _esn_like(cfg: esn.ESNConfig):
    return jax.eval_shape(lambda: esn.ESN(w_in=jnp.zeros((cfg.n_in, cfg.n_res)),
                                          w_res=jnp.zeros((cfg.n_res, cfg.n_res)),
                                          w_out=jnp.zeros((cfg.n_res, cfg.n_out))))


def save(directory: str | pathlib.Path, tl_params: tl.TLParams, tl_hyper: tl.TLHyper,
         agent: cacla.Agent, al_config: cacla.CaclaConfig, net: esn.ESN,
         esn_config: esn.ESNConfig, env_config: EnvConfig, extra: dict | None = None,
         free_modules: dict | None = None, agents: cacla.Agent | None = None,
         saved_agent: int = 0, frames_namers: dict | None = None) -> None:
    """Save the three trained modules (replacing an earlier save there only once the new one
    is complete).

    Args:
        directory: the folder to write.
        tl_params: the TL's parameters.
        tl_hyper: its hyperparameters (``hidden``, ``replication``, ``image_scale`` and
            ``target_scale`` as scalars).
        agent: one AL agent (unbatched).
        al_config: its config.
        net: the AN with its fitted readout.
        esn_config: its config.
        env_config: the env the agent was trained in.
        extra: JSON-able notes kept in the config (e.g. the profile and seed).
        free_modules: the free family's robot, optional: ``{"xy_params", "xy_config"
            (tl_xy.XYConfig), "agent", "al_config" (cacla.CaclaConfig), "env_config"}``,
            ``"params"`` (the `EnvParams` it was trained with; default
            ``EnvParams()``), optionally ``"agents"`` (every agent trained, stacked) with
            ``"saved_agent"`` (the index of ``"agent"`` among them) and, when a namer was
            trained for it, ``"net"`` and ``"esn_config"``.
        agents: every paper-family AL agent trained beside ``agent`` (stacked; optional:
            the robot can then watch, or act as, another of them).
        saved_agent: the index of ``agent`` among ``agents``.
        frames_namers: `grounding_jax.robot.seeing.FramesNamer` by family ("paper",
            "free"), optional (the robot can then `Robot.watch_frames`).
    """
    directory = pathlib.Path(directory)
    config = {
        "tl": {"hidden": int(tl_hyper.hidden), "replication": int(tl_hyper.replication),
               "image_scale": float(tl_hyper.image_scale),
               "target_scale": float(tl_hyper.target_scale),
               "max_hidden": int(tl_params.w1.shape[1]),
               "max_replication": (int(tl_params.w1.shape[0]) - tl.N_PIXELS) // tl.N_SYMBOLS},
        "al": dataclasses.asdict(al_config), "an": dataclasses.asdict(esn_config),
        "env": dataclasses.asdict(env_config), "extra": extra or {}}
    tree = {"tl": tl_params, "al": agent, "an": net}
    if agents is not None:
        config["al_agents"] = {"n_agents": _count(agents), "saved_agent": int(saved_agent)}
        _check_agents(config["al_agents"], "saved_agent")
        tree["al_agents"] = agents
    if free_modules is not None:
        config["free"] = {"xy": dataclasses.asdict(free_modules["xy_config"]),
                          "al": dataclasses.asdict(free_modules["al_config"]),
                          "env": dataclasses.asdict(free_modules["env_config"]),
                          "params": _params_json(free_modules.get("params", DEFAULT_PARAMS))}
        tree["free"] = {"xy": free_modules["xy_params"], "al": free_modules["agent"]}
        if free_modules.get("agents") is not None:
            agents = free_modules["agents"]
            config["free"]["n_agents"] = int(jax.tree.leaves(agents)[0].shape[0])
            config["free"]["saved_agent"] = int(free_modules["saved_agent"])
            tree["free"]["agents"] = agents
        if free_modules.get("net") is not None:
            config["free"]["an"] = dataclasses.asdict(free_modules["esn_config"])
            tree["free"]["an"] = free_modules["net"]
    if frames_namers:
        config["frames"] = seeing.namers_config(frames_namers)
        tree["frames"] = dict(frames_namers)
    directory.parent.mkdir(parents=True, exist_ok=True)
    with guard.folder_lock(directory.parent, f"saving {directory.name}"):
        tmp = directory.with_name(f".{directory.name}.tmp-{os.getpid()}")
        if tmp.exists():
            shutil.rmtree(tmp)
        try:
            with Checkpointer(tmp, KIND, config, max_to_keep=1) as ck:
                ck.save(0, tree)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)  # the earlier save stays as it was
            raise
        old = directory.with_name(f".{directory.name}.old-{os.getpid()}")
        if directory.exists():
            os.replace(directory, old)
        os.replace(tmp, directory)
        if old.exists():
            shutil.rmtree(old)


def save_robot(directory: str | pathlib.Path, robot: Robot, extra: dict | None = None) -> None:
    """Save a `Robot` as it is (e.g. a loaded one given ``frames_namers`` by
    ``dataclasses.replace``) with `save`; ``extra`` replaces its config's notes."""
    free = None
    if robot.free is not None:
        f = robot.free
        free = {"xy_params": f.xy_params, "xy_config": f.xy_config, "agent": f.al.agent,
                "al_config": f.al.config, "env_config": f.env_config, "params": f.params,
                "agents": f.agents, "saved_agent": f.saved_agent,
                "net": f.an.net if f.an else None, "esn_config": f.an.config if f.an else None}
    save(directory, robot.tl.params, robot.tl.hyper, robot.al.agent, robot.al.config,
         robot.an.net, robot.an.config, robot.env_config,
         extra=robot.config.get("extra") if extra is None else extra, free_modules=free,
         agents=robot.agents, saved_agent=robot.saved_agent or 0,
         frames_namers=robot.frames_namers)


def load(directory: str | pathlib.Path) -> Robot:
    """Load modules saved by `save` (``train.py`` writes ``results/<profile>/modules``).

    Raises:
        CheckpointError: no checkpoint there, another package version, a config.json edited
            after saving, damaged files or arrays (named), a config this version cannot
            build, or arrays that do not match it.
    """
    directory = pathlib.Path(directory)
    stored = read_config(directory)
    if stored["kind"] != KIND:
        raise CheckpointError(f"{directory}: holds a {stored['kind']!r} checkpoint, not "
                              f"trained modules ({KIND!r})")
    config = stored["config"]
    with Checkpointer(directory, KIND, config, read_only=True) as ck:
        step = ck.latest_step()
        if step is None:
            raise CheckpointError(f"{directory}: config.json but no complete checkpoint")
        ck.check_sealed(step)  # an edited config.json is refused before it is built
        tl_cfg, tl_hp, al_cfg, esn_cfg, env_cfg = _configs(config)
        tree = ck.restore(step, _like(config))
    modules_free = None
    if "free" in config:
        f = config["free"]
        modules_free = TrainedFree(
            xy_params=tree["free"]["xy"], xy_config=tl_xy.XYConfig(**f["xy"]),
            al=TrainedAL(tree["free"]["al"], cacla.CaclaConfig(**f["al"])),
            env_config=EnvConfig(**f["env"]),
            an=TrainedAN(tree["free"]["an"], esn.ESNConfig(**f["an"])) if "an" in f else None,
            # saves before the field existed acted with the defaults
            params=EnvParams(**f.get("params", {})),
            agents=tree["free"].get("agents"), saved_agent=f.get("saved_agent"))
    return Robot(tl=TrainedTL(tree["tl"], tl_hp),
                 al=TrainedAL(tree["al"], al_cfg), an=TrainedAN(tree["an"], esn_cfg),
                 env_config=env_cfg, config=config, free=modules_free,
                 agents=tree.get("al_agents"),
                 saved_agent=config.get("al_agents", {}).get("saved_agent"),
                 frames_namers=tree.get("frames"))


def seal(directory: str | pathlib.Path) -> None:
    """Seal trained modules saved before checksums were saved with them (grounding_jax
    0.1.0 of 2026-12-03 and earlier): write their step's manifest from the files as they
    are now. Trust the files first (e.g. they are as committed); `load` refuses
    modules without a manifest.

    Raises:
        CheckpointError: not a modules folder, already sealed, or unreadable.
    """
    directory = pathlib.Path(directory)
    stored = read_config(directory)
    if stored["kind"] != KIND:
        raise CheckpointError(f"{directory}: holds a {stored['kind']!r} checkpoint, not "
                              f"trained modules ({KIND!r})")
    with guard.folder_lock(directory.parent, f"sealing {directory.name}"), Checkpointer(
            directory, KIND, stored["config"]) as ck:
        step = ck.latest_step()
        if step is None:
            raise CheckpointError(f"{directory}: config.json but no complete checkpoint")
        ck.seal(step, _like(stored["config"]))

