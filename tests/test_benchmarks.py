"""The throughput benchmarks run end to end at a tiny batch on the CPU, so the commands in
the documentation stay runnable (the GPU ones, e.g. ``benchmarks/env_throughput.py --backends
mjx``, use the same code with the MJX env, which test_backends runs under jit/vmap/scan). They
only measure; nothing here times anything."""

from __future__ import annotations

import json
import math
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent


def _run(script: str, args: list[str], tmp_path: pathlib.Path) -> dict:
    out = tmp_path / f"{script}.json"
    env = {**os.environ, "GROUNDING_JAX_CACHE": str(tmp_path / "cache")}
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / f"{script}.py"), *args,
                           "--out", str(out)], capture_output=True, text=True, env=env,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(out.read_text())


def _rate(v) -> bool:
    return isinstance(v, float) and math.isfinite(v) and v > 0


def test_env_throughput_runs_at_a_tiny_batch(tmp_path):
    # the C backend only: an MJX row is the same code with backend="mjx" and costs a cold
    # MJX compile of its own (~40 s of CI); MJX's env runs under jit/vmap/scan in
    # test_backends; the docs' table comes from a run of both
    res = _run("env_throughput", ["--batches", "2", "--backends", "mujoco",
                                  "--steps", "2", "--repeats", "1"], tmp_path)
    rows = {r["backend"]: r for r in res["rows"]}
    assert set(rows) == {"mujoco"}
    for r in rows.values():
        assert r["batch"] == 2
        for k in ("rl_steps_per_s", "physics_steps_per_s", "compile_cold_s", "compile_warm_s"):
            assert _rate(r[k]), (r["backend"], k, r[k])
        assert r["physics_steps_per_s"] == r["rl_steps_per_s"] * res["meta"]["substeps"]
    assert _rate(rows["mujoco"]["rollout_alone_physics_steps_per_s"])


def test_al_throughput_runs_at_a_tiny_batch(tmp_path):
    res = _run("al_throughput", ["--batches", "2", "--episodes", "1", "--ref-agents", "1",
                                 "--loops", "auto_reset", "--mjx-batch", "0"], tmp_path)
    assert _rate(res["reference"]["rl_steps_per_s"])
    (row,) = res["rows"]
    assert (row["backend"], row["loop"], row["batch"]) == ("mujoco", "auto_reset", 2)
    for k in ("rl_steps_per_s", "ceiling_same_physics_rl_steps_per_s",
              "ceiling_resting_rl_steps_per_s", "over_reference", "of_ceiling_same_physics"):
        assert _rate(row[k]), (k, row[k])
    assert math.isclose(sum(row["split"].values()), 1.0)
    assert 0 < row["split"]["physics"] < 1
