"""The front door: the README's length, commands, links and quick starts; the documentation
site builds strictly; every public symbol of the API reference has a docstring; the generated
tables match their result files; the video command line writes a playable file."""

from __future__ import annotations

import importlib
import inspect
import os
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
COMMANDS = [
    "python3 -m venv .venv && . .venv/bin/activate && pip install -e . && python train.py",
    "python3 -m venv .venv && . .venv/bin/activate && pip install -e '.[test,ray]' && "
    "python -m pytest -q",
]
sys.path.insert(0, str(ROOT / "benchmarks"))


def _blocks(text: str, lang: str = "python") -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, re.S)


def test_the_readme_is_short_and_opens_with_the_two_commands():
    lines = README.splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines; keep it to 250"
    first = _blocks(README, "bash")[0].strip().splitlines()
    assert first == COMMANDS
    assert README.index("```bash") < README.index("## ")  # before any section


def test_every_relative_link_of_the_readme_and_the_docs_resolves():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    broken = []
    for page in pages:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" in target:
                continue
            if not (page.parent / target).exists():
                broken.append(f"{page.relative_to(ROOT)} -> {target}")
    assert not broken, broken


def test_the_docs_build_strictly(tmp_path):
    pytest.importorskip("mkdocs", reason="the docs extra (pip install -e '.[docs]')")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d",
                           str(tmp_path / "site")], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, done.stdout + done.stderr
    assert (tmp_path / "site" / "api" / "index.html").is_file()
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    assert "make_env" in api and "Robot" in api and "write_video" in api
    # docstrings are Markdown: no reStructuredText role reaches a page as literal text
    raw = {p.name: re.findall(r":(?:func|class|meth|mod|data|attr|exc|obj):", p.read_text())
           for p in (tmp_path / "site").rglob("*.html")}
    assert not {k: v for k, v in raw.items() if v}, raw


def _api_modules() -> list[str]:
    return re.findall(r"^::: (\S+)", (ROOT / "docs" / "api.md").read_text(), re.M)


def test_every_public_symbol_of_the_api_reference_has_a_docstring():
    missing = []
    for name in _api_modules():
        module = importlib.import_module(name)
        for attr, obj in vars(module).items():
            if attr.startswith("_") or not (inspect.isfunction(obj) or inspect.isclass(obj)):
                continue
            if getattr(obj, "__module__", None) != name:
                continue  # imported from elsewhere: documented there
            if not (obj.__doc__ or "").strip():
                missing.append(f"{name}.{attr}")
            if inspect.isclass(obj):
                missing += [f"{name}.{attr}.{m}" for m, f in vars(obj).items()
                            if not m.startswith("_") and inspect.isfunction(f)
                            and not (f.__doc__ or "").strip()]
    assert not missing, f"public symbols without a docstring: {missing}"


def test_the_public_names_the_readme_uses_are_importable_from_the_package():
    import grounding_jax as gj

    for name in ("make_env", "make_task", "load", "frames", "write_video",
                 "enable_compilation_cache", "Env", "EnvConfig", "EnvParams", "Robot"):
        assert callable(getattr(gj, name)), name


def test_the_headline_tables_match_the_result_files():
    from grounding_jax.paper import headline

    assert headline.main(["--check"]) == 0
    rows = headline.table({**_paper_metrics()})
    assert rows in README  # and the README shows them
    with pytest.raises(ValueError, match="headline"):
        headline.replace("no markers here", rows)


def _paper_metrics() -> dict:
    import json

    return json.loads((ROOT / "results" / "paper" / "metrics.json").read_text())


def test_the_tuning_index_matches_its_files():
    import tuning_index

    assert tuning_index.main(["--check"]) == 0
    text = tuning_index.index()
    files = sorted((ROOT / "results" / "tuning").glob("*.json"))
    assert files and all(f"`{p.name}`" in text for p in files)
    assert not list((ROOT / "results" / "benchmarks").glob("free_tuning_*.json"))


@pytest.fixture(scope="module")
def in_a_folder_with_the_results(tmp_path_factory):
    """A fresh folder where ``results/`` is the checkout's (the examples read the committed
    modules and write their videos here)."""
    folder = tmp_path_factory.mktemp("examples")
    (folder / "results").symlink_to(ROOT / "results")
    return folder


def test_the_readme_quick_starts_run(in_a_folder_with_the_results, monkeypatch, capsys):
    monkeypatch.chdir(in_a_folder_with_the_results)
    robot_block, env_block = _blocks(README)
    exec(compile(robot_block, "README.md", "exec"), {})
    assert capsys.readouterr().out.split()[:2] == ["right", "right"]
    video = in_a_folder_with_the_results / "push_red.mp4"
    assert _frames_of(video) == 100
    exec(compile(env_block, "README.md", "exec"), {})
    assert capsys.readouterr().out.strip() == "(64, 20)"


def test_the_robot_pages_video_example_runs(in_a_folder_with_the_results, monkeypatch):
    monkeypatch.chdir(in_a_folder_with_the_results)
    text = (ROOT / "docs" / "robot.md").read_text()
    code = _blocks(text[text.index("## Seeing the robot"):])[0]
    scope: dict = {}
    exec(compile(code, "docs/robot.md", "exec"), scope)
    assert scope["images"].shape == (100, 320, 480, 3)
    from PIL import Image

    with Image.open(in_a_folder_with_the_results / "touch_green.gif") as gif:
        assert gif.n_frames == 50 and gif.size == (480, 320)


def _frames_of(video: pathlib.Path) -> int:
    import imageio_ffmpeg

    frames, _ = imageio_ffmpeg.count_frames_and_secs(str(video))
    return frames


def _show(*args: str, cwd: pathlib.Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grounding_jax.show", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


def test_the_video_command_line_writes_a_playable_file(tmp_path):
    done = _show("push red", "--layout", "3", "--steps", "6", "--width", "64", "--height",
                 "48", "--out", "push_red.mp4", "--strip", "strip.png", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "the robot named it: push red" in done.stdout
    assert _frames_of(tmp_path / "push_red.mp4") == 6
    import cv2

    assert cv2.imread(str(tmp_path / "strip.png")).shape == (48, 4 * 64, 3)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporaries


def test_the_video_command_line_shows_objects_anywhere(tmp_path, monkeypatch, capsys):
    from PIL import Image

    from grounding_jax import show

    monkeypatch.chdir(tmp_path)
    assert show.main(["touch sphere", "--placement", "random", "--seed", "4", "--steps", "4",
                      "--width", "64", "--height", "48", "--out", "touch.gif"]) == 0
    out = capsys.readouterr().out
    assert "touch sphere, objects placed at random (seed 4): the TL put the sphere" in out
    assert re.search(r"at \(-?\d+\.\d, -?\d+\.\d\) cm, truly \(-?\d+\.\d, -?\d+\.\d\) cm", out)
    assert "left" not in out and "the robot named it: " in out
    with Image.open(tmp_path / "touch.gif") as gif:
        assert gif.n_frames == 4 and gif.size == (64, 48)


@pytest.mark.parametrize(("args", "message"), [
    (["push rd", "--out", "x.mp4"], "unknown target 'rd'; accepted values"),
    (["jump red", "--out", "x.mp4"], "unknown action 'jump'; accepted values"),
    (["push red", "--layout", "36", "--out", "x.mp4"], "--layout: 36 out of range"),
    (["push red", "--out", "x.avi"], "accepted suffixes: ('.mp4', '.gif')"),
    (["push red", "--placement", "anywhere", "--out", "x.mp4"], "--placement: unknown value"),
    (["push red"], "--out: say where to write the video"),
    (["push red", "--out", "x.mp4", "--modules", "nowhere"], "--modules: nowhere holds no"),
    (["push red", "--out", "no/such/folder/x.mp4"], "--out: the folder of"),
    (["push red", "--out", "x.mp4", "--camera", "top"], "--camera: unknown value 'top'"),
    (["push red", "--out", "x.mp4", "--steps", "0"], "--steps: 0 is not accepted"),
])
def test_the_video_command_line_names_a_bad_argument(tmp_path, monkeypatch, capsys, args,
                                                    message):
    from grounding_jax import show

    monkeypatch.chdir(tmp_path)
    assert show.main(args) == 2  # before anything loads or compiles
    err = capsys.readouterr().err
    assert message in err, err
    assert list(tmp_path.iterdir()) == []


def test_write_video_refuses_a_missing_ffmpeg(tmp_path, monkeypatch):
    import numpy as np

    from grounding_jax.sim import render

    monkeypatch.setenv("GROUNDING_JAX_FFMPEG", str(tmp_path / "no-ffmpeg"))
    with pytest.raises(RuntimeError, match="GROUNDING_JAX_FFMPEG"):
        render.write_video(tmp_path / "x.mp4", np.zeros((2, 8, 8, 3), np.uint8))
    monkeypatch.delenv("GROUNDING_JAX_FFMPEG")
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # importing it now fails
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(RuntimeError, match="needs ffmpeg.*pip install imageio-ffmpeg"):
        render.write_video(tmp_path / "x.mp4", np.zeros((2, 8, 8, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []


def test_every_import_in_the_docs_examples_works():
    """The examples of every page import what exists (the package's layout moved once)."""
    bad = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for block in _blocks(page.read_text()):
            for line in block.splitlines():
                if re.match(r"\s*(from|import) ", line):
                    try:
                        exec(line.strip(), {})
                    except ImportError as e:
                        bad.append(f"{page.relative_to(ROOT)}: {line.strip()} ({e})")
    assert not bad, bad


def test_the_docs_measured_tables_match_their_result_files():
    import doc_tables

    assert doc_tables.main(["--check"]) == 0
    marked = re.findall(r"<!-- table: (\w+) -->",
                        "".join(p.read_text() for p in (ROOT / "docs").glob("*.md")))
    assert sorted(marked) == sorted(doc_tables.TABLES)
    with pytest.raises(ValueError, match="unknown table 'nope'"):
        doc_tables.rewrite("<!-- table: nope -->\nx\n<!-- end table -->", "page")
