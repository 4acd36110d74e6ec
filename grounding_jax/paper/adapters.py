"""The AL and TL sweep adapters: how the sweep runner builds, trains, evaluates and reads
back the action learner (the paper's and the free family's) and the target localizer.

They reach the runner through the package's ``grounding_jax.sweep_adapters`` entry points
(``al``, ``tl``); the runner imports none of this.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core.checkpoint import CheckpointError
from grounding_jax.learn import al, cacla, tl
from grounding_jax.paper import al_eval
from grounding_jax.paper.beyond import FREE_LEARNER
from grounding_jax.sim import env, physics, tl_data
from grounding_jax.sim.env import EnvConfig, EnvParams
from grounding_jax.sweep.batching import chunk_stops, restore_to_resume
from grounding_jax.sweep.spec import Adapter, Field, Pieces, SweepSpec, field_from, traced_fields

#: the random starts of the success evaluation are drawn from this fixed key -- the same
#: evaluation set for every run and sweep, as a test set is
EVAL_SEED = 0

_DH, _EC = al.ALHyper(), EnvConfig()
#: the learner AL sweeps train (its traced fields are sweep fields, read from its rule table)
_LEARNER = cacla.LEARNER
_LH = _LEARNER.hyper_type()
_EP, _TH, _TC = EnvParams(), tl.TLHyper(), tl.TLConfig()




def _traced(rule, default):
    return field_from("traced", rule, default)


def _static(rule, default):
    return field_from("static", rule, default)


#: the traced AL fields a sweep may set, by the dataclass they belong to (the hidden sizes
#: are the sweep's own: they become ``actor_units``/``critic_units``)
_AL_SWEPT = {
    # all the learner's but the phase switch (the schedule sets it) and the units in use
    "learner": tuple(n for n in _LEARNER.hyper_rules
                     if n not in ("phase1", "actor_units", "critic_units")),
    "al": tuple(al.HYPER_RULES),  # ALHyper's own
    "env": ("action_scale", "touch_other_penalty", "touch_target_penalty",
            "touch_moved_penalty", "touch_bonus", "start_noise"),  # EnvParams
}

_FIELDS: dict[str, dict[str, Field]] = {
    "al": {
        # traced: the networks are built at the sweep's largest sizes with the unused units at
        # zero weights, where they stay (cacla.init) -- one batch instead of one per size, which
        # pays because an AL step's cost hardly grows with the batch (physics call overhead)
        "actor_hidden": _traced(cacla.CONFIG_RULES["actor_hidden"], 40),
        "critic_hidden": _traced(cacla.CONFIG_RULES["critic_hidden"], 20),
        "var": Field("static", bool, False),
        "phase1_episodes": _static(al.CONFIG_RULES["phase1_episodes"], 150),
        "phase2_episodes": _static(al.CONFIG_RULES["phase2_episodes"], 300),
        "backend": Field("static", str, _EC.backend, choices=physics.BACKENDS),
        "substeps": _static(env.CONFIG_RULES["substeps"], _EC.substeps),
        "episode_length": _static(env.CONFIG_RULES["episode_length"], _EC.episode_length),
        "random_layout": Field("static", bool, True),
        # "random": the free family (objects anywhere, the actor told the target's (x, y))
        "placement": Field("static", str, "fixed", choices=al.PLACEMENTS),
        **traced_fields(_LEARNER.hyper_rules, _LH, _AL_SWEPT["learner"]),
        **traced_fields(al.HYPER_RULES, _DH, _AL_SWEPT["al"]),
        **traced_fields(env.PARAM_RULES, _EP, _AL_SWEPT["env"]),
    },
    "tl": {
        # the hidden size could be traced (padded + masked), but one compile per size was
        # measured faster (benchmarks/tl_throughput.py), so it is a group key
        "hidden": _static(tl.HYPER_RULES["hidden"], _TH.hidden),
        "epochs": _static(tl.CONFIG_RULES["epochs"], _TC.epochs),
        "eval_every": _static(tl.CONFIG_RULES["eval_every"], _TC.eval_every),
        "noise_mode": Field("static", str, _TC.noise_mode, choices=tl.NOISE_MODES),
        **traced_fields(tl.HYPER_RULES, _TH,
                       ("lr", "replication", "noise", "image_scale", "target_scale")),
    },
}

#: the per-run metrics a figure may plot: AL -- per-episode training metrics (the summary is
#: the mean over the last tenth of the episodes); TL -- the final value after training
_METRICS = {
    "al": {"td_error": "critic's RMS TD error per episode",
           "final_reward": "reward at the episode's last step",
           "return": "sum of rewards over the episode",
           "final_point_l1": "L1 distance to the pointing pose at the episode's end",
           # evaluated at ``eval_at`` episodes (the greedy actor, the success criteria):
           **{f"success_{k}": f"success rate: {v}" for k, v in (
               ("point", "point from home"), ("touch", "touch from home"),
               ("push", "push from home"), ("rand_point", "point from random starts"),
               ("mean", "mean of point, touch, push and random-start point"))}},
    "tl": {"test_acc": "test accuracy", "train_acc": "training accuracy",
           "test_rmse": "test RMSE per output unit", "train_rmse": "training RMSE"},
}
#: metrics where lower is better (for the others higher is)
LOWER_IS_BETTER = frozenset({"td_error", "final_point_l1", "test_rmse", "train_rmse"})


def _al_config(pts: list[dict], static: dict[str, Any]) -> al.ALConfig:
    # random placements: the free family, with its networks (FREE_LEARNER's heads)
    learner = FREE_LEARNER if static["placement"] == "random" else cacla.CaclaConfig()
    return al.ALConfig(
        env=EnvConfig(backend=static["backend"], substeps=static["substeps"],
                      episode_length=static["episode_length"], task_set=learner.task_set),
        learner=dataclasses.replace(learner, actor_hidden=max(p["actor_hidden"] for p in pts),
                                    critic_hidden=max(p["critic_hidden"] for p in pts),
                                    var=static["var"]),
        phase1_episodes=static["phase1_episodes"],
        phase2_episodes=static["phase2_episodes"], random_layout=static["random_layout"],
        placement=static["placement"])


def _tl_config(pts: list[dict], static: dict[str, Any]) -> tl.TLConfig:
    clean = all(p["noise"] == 0 for p in pts)
    return tl.TLConfig(epochs=static["epochs"], eval_every=static["eval_every"],
                       noise_mode=static["noise_mode"], max_hidden=static["hidden"],
                       max_replication=max(p["replication"] for p in pts),
                       pixel_budget=int(tl_data.load().bitmaps.sum(1).max()) if clean else 0)


def _column(rows: list[dict], k: str, dtype) -> jnp.ndarray:
    return jnp.asarray([r[k] for r in rows], dtype)



def _al_hyper(rows: list[dict]) -> al.ALHyper:
    f32 = jnp.float32
    lh = _LEARNER.hyper_type(**{k: _column(rows, k, f32) for k in _AL_SWEPT["learner"]},
                             actor_units=_column(rows, "actor_hidden", jnp.int32),
                             critic_units=_column(rows, "critic_hidden", jnp.int32))
    env_params = EnvParams(**{k: _column(rows, k, f32) for k in _AL_SWEPT["env"]})
    return al.ALHyper(learner=lh, env=env_params,
                      **{k: _column(rows, k, f32) for k in _AL_SWEPT["al"]})


def _al_saved_like(cfg: al.ALConfig, keys: jax.Array, n_evals: int) -> dict:
    """The structure of an AL group's checkpoint (shapes only)."""
    n = keys.shape[0]
    like_agents = jax.eval_shape(lambda k: jax.vmap(lambda kk: al.schedule(kk, cfg)[0])(k),
                                 keys)  # shapes only: the units in use do not change them
    like_m = jax.eval_shape(lambda k: jax.vmap(al.make_train(
        dataclasses.replace(cfg, phase1_episodes=0, phase2_episodes=1)),
        in_axes=(0, None))(k, al.ALHyper())[1], keys)
    like_m = {k: jax.ShapeDtypeStruct((n, cfg.episodes), v.dtype) for k, v in like_m.items()}
    like = {"agents": like_agents, "metrics": like_m, "keys": keys, "episode": np.int64(0)}
    if n_evals:  # orbax stores no empty arrays
        like["evals"] = np.zeros((len(al_eval.SUCCESS_METRICS), n, n_evals), np.float32)
    return like


def _run_al(cfg: al.ALConfig, keys, hp, spec: SweepSpec, sharding, ck, progress):
    """Train a group in chunks of ``spec.chunk`` episodes; at each of ``spec.evaluations()``
    (episode counts) the success rates of every run are measured (the evaluation hook) and
    returned as metrics ``success_<name>`` ``[runs, len(evaluations)]``."""
    evaluations = spec.evaluations()
    stops = sorted(set(chunk_stops(cfg.episodes, spec.chunk)) | set(evaluations))
    start = None
    n = keys.shape[0]
    names = al_eval.SUCCESS_METRICS
    evals = np.full((len(names), n, len(evaluations)), np.nan, np.float32)
    rates = al_eval.make_success_rates(cfg.env) if evaluations else None
    found = None if ck is None or not ck.steps() else restore_to_resume(
        ck, _al_saved_like(cfg, keys, len(evaluations)))
    if found is not None:
        saved = found[1]
        if not np.array_equal(jax.random.key_data(saved["keys"]), jax.random.key_data(keys)):
            raise CheckpointError(f"{ck.directory}: stored run keys differ from this run's")
        start = (int(saved["episode"]), saved["agents"], saved["metrics"])
        if evaluations:
            evals = np.asarray(saved["evals"], np.float32)
        if progress:
            progress(n * start[0])
    done = [start[0] if start else 0]

    def on_stop(episode, agents, metrics):
        if episode in evaluations:
            r = rates(agents, jax.random.key(EVAL_SEED), hp.env)
            for i, k in enumerate(names):
                evals[i, :, evaluations.index(episode)] = r[k]
        if ck is not None:
            tree = {"agents": agents, "metrics": metrics, "keys": keys,
                    "episode": np.int64(episode)}
            ck.save(episode, tree | ({"evals": evals} if evaluations else {}))
        if progress:
            progress(n * (episode - done[0]))
        done[0] = episode

    agents, metrics = al.train_in_chunks(cfg, keys, hp, stops, on_stop, start, sharding)
    if evaluations:
        metrics = {**metrics, **{f"success_{k}": evals[i] for i, k in enumerate(names)}}
    return metrics, agents


def _run_tl(cfg: tl.TLConfig, keys, hp, spec: SweepSpec, sharding, ck, progress):
    n = keys.shape[0]
    train = jax.jit(jax.vmap(tl.make_train(cfg)))
    found = None if ck is None or not ck.steps() else restore_to_resume(
        ck, jax.eval_shape(train, keys, hp))
    if found is not None:
        params, metrics = found[1]
    else:
        keys, hp = jax.device_put((keys, hp), sharding)
        params, metrics = jax.block_until_ready(train(keys, hp))
        if ck is not None:
            ck.save(1, (params, metrics))
    if progress:
        progress(n * cfg.epochs)
    return metrics, params




def _nbytes(tree) -> int:
    def size(x) -> int:  # a typed PRNG key is stored as its key data (2 uint32 words)
        item = 8 if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key) else np.dtype(
            x.dtype).itemsize
        return int(np.prod(x.shape)) * item

    return sum(size(x) for x in jax.tree.leaves(tree))


#: memory a run takes beside its own arrays, whatever its length: the physics step's
#: buffers and XLA's temporaries, measured as the slope of peak RSS over batch size (1,024 to
#: 8,192 runs of 2 episodes, chunk 2: 62 KB a run; 16 to 128 runs of 100 episodes, chunk 50:
#: ~270 KB a run, noisy) less what the formula below counts
_AL_RUN_OVERHEAD = 56_000
#: copies of an episode's first state a chunk holds (the reset states of every episode of the
#: chunk, the selected ones, the loop's carry), fitted with the figures above
_AL_STATE_COPIES = 8


#: bytes of an episode's metrics, an upper bound (16 float32 values; the AL records ~10)
_AL_EPISODE_METRICS = 64


@functools.lru_cache(maxsize=32)
def _al_run_bytes(cfg: al.ALConfig, chunk: int, n_evals: int) -> int:
    # shapes only, and without tracing the trainer (its traces are counted: one per group)
    agent = jax.eval_shape(lambda k: al.schedule(k, cfg), jax.random.key(0))
    saved = (_nbytes(agent) + cfg.episodes * _AL_EPISODE_METRICS
             + 4 * n_evals * len(al_eval.SUCCESS_METRICS))
    task = env.make_task("point", 0, 0, cfg.env.task_set)
    state = _nbytes(jax.eval_shape(env.Env(cfg.env).reset, jax.random.key(0), task,
                                   EnvParams()))
    return saved + min(chunk, cfg.episodes) * _AL_STATE_COPIES * state + _AL_RUN_OVERHEAD


@functools.lru_cache(maxsize=32)
def _tl_run_bytes(cfg: tl.TLConfig) -> int:
    data = tl_data.load()
    n_in = data.bitmaps.shape[1] + 15 * cfg.max_replication
    inputs = data.bitmaps.shape[0] * n_in * 4
    params = 4 * (n_in * cfg.max_hidden + cfg.max_hidden + 4 * cfg.max_hidden + 4)
    # the run's params with their gradients and update, and two copies of the inputs (its
    # own, noisy and scaled, and XLA's temporaries): the slope of peak RSS over 64 to 1,024
    # runs of the paper's TL, 2 epochs, was 2.5 MB a run, this formula's figure 3.5 MB
    return 3 * params + 2 * inputs


@functools.lru_cache(maxsize=8)
def _al_pieces(cfg: al.ALConfig) -> Pieces:
    """The AL trained piece by piece (ASHA, PBT), its success rates measured as a grid's are
    (the same evaluation set, `EVAL_SEED`)."""
    start, advance = al.make_pieces(cfg)
    found = []

    def rates(state, hp) -> dict:
        if not found:  # built on first use: a search ranking by a curve never needs it
            found.append(al_eval.make_success_rates(cfg.env))
        return found[0](state["agent"], jax.random.key(EVAL_SEED), hp.env)

    return Pieces(start, advance, rates)


#: the action learner: the paper's (fixed slots) and the free family's (``placement = "random"``)
AL = Adapter(_FIELDS["al"], _METRICS["al"], "episodes",
             lambda p: p["phase1_episodes"] + p["phase2_episodes"], _al_config, _al_hyper,
             _run_al, curves=True, evaluates=True, success=al_eval.SUCCESS_METRICS,
             lower_is_better=LOWER_IS_BETTER, saved_like=_al_saved_like, pieces=_al_pieces,
             run_bytes=lambda cfg, spec: _al_run_bytes(cfg, spec.chunk,
                                                       len(spec.evaluations())))
#: the target localizer
TL = Adapter(_FIELDS["tl"], _METRICS["tl"], "epochs", lambda p: p["epochs"], _tl_config,
             tl.stack_hyper, _run_tl, lower_is_better=LOWER_IS_BETTER,
             run_bytes=lambda cfg, spec: _tl_run_bytes(cfg))
