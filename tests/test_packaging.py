"""The package as users get it: a wheel installed outside the checkout, and an import that
leaves JAX's settings alone."""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import sys
import zipfile

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
MODULES = ROOT / "results" / "paper" / "modules"


def _run(code: str, cwd: pathlib.Path, **env: str) -> str:
    proc = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True,
                          text=True, env={**os.environ, **env}, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_import_changes_no_jax_setting_and_the_cache_is_switched_on_explicitly(tmp_path):
    cache = tmp_path / "cache"
    out = _run(
        "import json, jax\n"
        "keys = ('jax_compilation_cache_dir', 'jax_persistent_cache_min_compile_time_secs',"
        " 'jax_persistent_cache_min_entry_size_bytes')\n"
        "get = lambda: [getattr(jax.config, k) for k in keys]\n"
        "before = get()\n"
        "import grounding_jax\n"
        "after_import = get()\n"
        "where = grounding_jax.enable_compilation_cache()\n"
        "print(json.dumps([before, after_import, where, get()]))\n",
        tmp_path, GROUNDING_JAX_CACHE=str(cache))
    before, after_import, where, after_enable = json.loads(out.splitlines()[-1])
    assert after_import == before
    assert where == str(cache) and cache.is_dir()
    assert after_enable[0] == str(cache) and after_enable != before


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> pathlib.Path:
    """The project built as a wheel and installed (no dependencies) into a private folder."""
    tmp = tmp_path_factory.mktemp("wheel")
    # from a copy of what the build reads, so no stale build/ folder of the checkout leaks in;
    # built as pip builds it for users (an isolated build env, as the CI's editable install)
    src = tmp / "src"
    shutil.copytree(ROOT / "grounding_jax", src / "grounding_jax",
                    ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.pyd"))
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy(ROOT / name, src / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w",
                    str(tmp / "dist"), str(src)], check=True, capture_output=True, timeout=600)
    (wheel,) = (tmp / "dist").glob("grounding_jax-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for data in ("table_scene.xml", "pointing_configs.json", "tl_bitmaps.npz"):
        assert f"grounding_jax/sim/assets/{data}" in names
    site = tmp / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target",
                    str(site), str(wheel)], check=True, capture_output=True, timeout=600)
    return site


def test_the_installed_wheel_builds_the_scene_renders_and_loads_modules_outside_the_checkout(
        installed, tmp_path):
    code = f"""
import json, pathlib
import jax, numpy as np
import grounding_jax as gj
from grounding_jax.sim import tl_data, vision
here = pathlib.Path(gj.__file__).resolve()
env = gj.make_env("mujoco")
state = env.step(env.reset(jax.random.key(0), gj.make_task("point", 0, 3)), jax.numpy.zeros(4))
try:
    bitmap = vision.bitmap_from_image(vision.eye_renderer().render(3))
    rendered = bool(np.array_equal(bitmap, tl_data.cached_bitmaps()[3]))
except RuntimeError as e:  # no headless GL on this machine
    rendered = str(e)
robot = gj.load({str(MODULES)!r})
from grounding_jax import sweep  # its adapters come through the wheel's entry points
spec = sweep.parse_spec({{"module": "tl", "grid": {{"hidden": [3]}}}})
import grounding_jax.paper.adapters as adapters
from grounding_jax.sim import physics
print(json.dumps({{"file": str(here), "handler": physics.step_handler(),
                  "obs": np.asarray(state.obs).tolist(),
                  "rendered": rendered, "red": robot.tl.localize(3, "red"),
                  "truth": tl_data.label_of(3, tl_data.word_index("red")),
                  "modules": sorted(sweep.FIELDS), "adapters": adapters.__file__,
                  "points": len(spec.points())}}))
"""
    out = json.loads(_run(code, tmp_path, PYTHONPATH=str(installed)).splitlines()[-1])
    assert pathlib.Path(out["file"]).is_relative_to(installed.resolve())  # not the checkout
    assert len(out["obs"]) == 11 and all(map(lambda v: v == v, out["obs"]))
    assert out["modules"] == ["al", "tl"] and out["points"] == 1
    assert pathlib.Path(out["adapters"]).is_relative_to(installed.resolve())
    # the wheel holds the compiled physics step wherever a C++ compiler built it
    import shutil

    if shutil.which("c++") or shutil.which("g++"):
        assert out["handler"] == "compiled"
    if isinstance(out["rendered"], str):
        pytest.skip(f"no headless OpenGL backend: {out['rendered']}")
    assert out["rendered"] is True  # the camera sees what the shipped bitmaps hold
    assert out["red"] == out["truth"]


def test_the_mjx_backend_imports_without_the_warp_message(tmp_path):
    # mujoco.mjx prints two "Failed to import warp" lines when its optional Warp backend is
    # missing; the package never uses it, so its users should not read them
    out = _run("from grounding_jax.sim import physics\nphysics.import_mjx()\nprint('ok')",
               tmp_path)
    assert out == "ok\n", out
