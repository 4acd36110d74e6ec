"""Naming from frames (grounding_jax.robot.seeing): the pixel labels and features on drawn
scenes with known answers, the namer's fit, and a robot saved with namers that loads and
names rendered frames alike."""

from __future__ import annotations

import dataclasses
import json
import pathlib

import jax
import numpy as np
import pytest

from grounding_jax.core.checkpoint import CheckpointError
from grounding_jax.robot import seeing, trained

QUICK = pathlib.Path(__file__).resolve().parents[1] / "results" / "quick" / "modules"
H, W, T = 40, 60, 10
F = {name: i for i, name in enumerate(seeing.FEATURES)}


def _scene(hand_to: tuple[int, int] | None, red_shift: int = 0) -> np.ndarray:
    """T frames of the table with a red (cols 10-15), green (28-33) and blue (46-51) square
    at rows 24-29, a still grey body top left and a grey hand moving from (5, 5) to
    ``hand_to`` (row, col); the red square slides ``red_shift`` columns over the episode."""
    out = np.empty((T, H, W, 3), np.uint8)
    out[:] = seeing.TABLE_RGB
    out[:, :8, :] = 0  # the background behind the table
    out[:, 2:6, 50:58] = (120, 120, 125)  # the body: grey, still
    for t in range(T):
        s = round(red_shift * t / (T - 1))
        out[t, 24:30, 10 + s:16 + s] = (190, 20, 20)
        out[t, 24:30, 28:34] = (20, 128, 20)
        out[t, 24:30, 46:52] = (25, 38, 190)
        if hand_to is not None:
            r = round(5 + (hand_to[0] - 5) * min(1.0, 2 * t / (T - 1)))
            c = round(5 + (hand_to[1] - 5) * min(1.0, 2 * t / (T - 1)))
            out[t, r - 2:r + 1, c - 2:c + 3] = (240, 240, 240)
    return out


def test_pixels_are_labelled_table_object_colour_and_robot():
    lab = seeing.label_frames(_scene((20, 30))[:1])[0]
    assert lab[0, 0] == seeing.NOTHING and lab[35, 5] == seeing.NOTHING  # background, table
    assert lab[26, 12] == 1 and lab[26, 30] == 2 and lab[26, 48] == 3  # red, green, blue
    assert lab[4, 52] == seeing.ARM  # the grey body


def test_features_say_where_the_hand_went_and_what_moved():
    still = seeing.features(_scene((22, 13)))  # the hand comes down over the red square
    assert still.shape == (3, seeing.N_FEATURES) and still.dtype == np.float32
    red, green = still[0], still[1]
    assert red[F["arm_in_column_end"]] > 0.5 > green[F["arm_in_column_end"]]
    assert abs(red[F["hand_dx_end"]]) < 2 / W < abs(green[F["hand_dx_end"]])
    assert np.all(still[:, F["moved_max"]] == 0)
    moved = seeing.features(_scene((22, 13), red_shift=6))
    # the centroid slid 6 px: 0.1 of the width (features are fractions of the width)
    assert moved[0, F["moved_max"]] == pytest.approx(6 / W, abs=1e-6)
    assert moved[1, F["moved_max"]] == 0
    # a frame twice as large reads alike
    big = seeing.features(np.repeat(np.repeat(_scene((22, 13)), 2, 1), 2, 2))
    np.testing.assert_allclose(big[:, F["hand_dx_end"]], still[:, F["hand_dx_end"]], atol=0.03)


def test_both_cameras_read_each_view_alone_and_join_their_features():
    left, right = _scene((22, 13)), _scene((22, 47), red_shift=6)
    both = seeing.features(np.concatenate([left, right], 2), "both")
    assert both.shape == (3, seeing.n_features("both")) == (3, 2 * seeing.N_FEATURES)
    np.testing.assert_array_equal(both, np.concatenate(
        [seeing.features(left), seeing.features(right)], -1))
    with pytest.raises(ValueError, match="even width"):
        seeing.features(np.concatenate([left, right[:, :, 1:]], 2), "both")
    with pytest.raises(ValueError, match="camera: unknown value 'side'"):
        seeing.features(left, "side")
    # a namer of the joined features restores from its checkpoint's sizes
    net = seeing.like(4, 3, "both", members=2)
    assert net.w1.shape == (2, 2 * seeing.N_FEATURES, 4)
    back = seeing.namers_like(seeing.namers_config({"paper": net}))["paper"]
    assert back.camera == "both" and back.w1.shape == net.w1.shape
    names = ("point", "touch", "push")
    frames = np.concatenate([left, right], 2)
    assert seeing.watch({"paper": net}, frames, "paper", names, camera="both") == (
        names[seeing.best(net, both)[0]], seeing.COLOURS[seeing.best(net, both)[1]])
    with pytest.raises(ValueError, match=r"feats: shape .*\[N, 3, 30\]"):
        seeing.fit(jax.random.key(0), np.zeros((4, 3, seeing.N_FEATURES)), np.zeros(4, int),
                   np.zeros(4, int), 3, camera="both")


def test_the_fitted_namer_separates_what_it_was_shown():
    rng = np.random.default_rng(0)
    action, target = rng.integers(3, size=60), rng.integers(3, size=60)
    feats = rng.normal(size=(60, 3, seeing.N_FEATURES)).astype(np.float32)
    feats[np.arange(60), target, action] += 4.0  # action a: feature a is high on the target
    net = seeing.fit(jax.random.key(0), feats, action, target, 3, steps=400)
    named = [seeing.best(net, f)[:2] for f in feats]
    assert np.mean([n == (a, c) for n, a, c in zip(named, action, target, strict=True)]) >= 0.95


@pytest.mark.parametrize("frames", [np.zeros((5, 20, 30, 3), np.float32),
                                    np.zeros((1, 20, 30, 3), np.uint8),
                                    np.zeros((5, 20, 30), np.uint8)])
def test_frames_of_another_shape_or_type_are_refused(frames):
    with pytest.raises(ValueError, match="frames: got .* accepted: uint8"):
        seeing.check_frames(frames)


def test_a_robot_without_a_namer_says_how_to_get_one():
    net = seeing.like(4, 3)
    with pytest.raises(ValueError, match="no frames namer for 'free'.*watch_frames stage"):
        seeing.watch({"paper": net}, _scene((20, 30)), "free", ("point", "touch", "push"))
    with pytest.raises(ValueError, match="family: 'eye' not accepted"):
        seeing.watch({"paper": net}, _scene((20, 30)), "eye", ("point", "touch", "push"))
    # frames of another camera than the namer's would be read as nonsense: refused
    with pytest.raises(ValueError, match="camera: 'eye', but .* fitted on frames of the "
                                         "'observer' camera"):
        seeing.watch({"paper": net}, _scene((20, 30)), "paper", ("point", "touch", "push"),
                     camera="eye")


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """The committed quick robot saved again with a frames namer (random weights)."""
    robot = trained.load(QUICK)
    net = seeing.like(4, 3, members=2).replace(
        w1=jax.random.normal(jax.random.key(1), (2, seeing.N_FEATURES, 4)),
        w2=jax.random.normal(jax.random.key(2), (2, 4, 3)))
    out = tmp_path_factory.mktemp("seeing") / "modules"
    trained.save_robot(out, dataclasses.replace(robot, frames_namers={"paper": net}))
    return robot, net, out


def test_a_robot_saved_with_its_namer_loads_and_names_frames_alike(saved):
    import grounding_jax as gj

    robot, net, out = saved
    back = gj.load(out)
    np.testing.assert_array_equal(back.frames_namers["paper"].w1, net.w1)
    assert back.n_agents == robot.n_agents and back.config["frames"]["paper"] == {
        "hidden": 4, "n_actions": 3, "members": 2, "camera": "observer"}
    frames = gj.frames(robot.perform("push", "red", layout=3), width=120, height=80, every=5)
    want = seeing.watch({"paper": net}, frames, "paper", robot.env_config.tasks.action_names)
    assert back.watch_frames(frames) == want
    assert back.watch_frames(np.stack([frames, frames])) == [want, want]
    with pytest.raises(ValueError, match="no frames namer"):
        robot.watch_frames(frames)  # the robot as train.py saved it holds none


def test_frames_of_both_cameras_are_the_two_views_side_by_side(saved):
    import grounding_jax as gj

    ep = saved[0].perform("touch", "green", layout=5)
    both = gj.frames(ep, camera="both", width=60, height=40, every=10)
    assert both.shape == (10, 40, 120, 3)
    np.testing.assert_array_equal(both[:, :, :60], gj.frames(ep, width=60, height=40, every=10))
    np.testing.assert_array_equal(both[:, :, 60:], gj.frames(ep, camera="eye", width=60,
                                                             height=40, every=10))
    with pytest.raises(ValueError, match="camera: unknown value 'top'.*'both'"):
        gj.frames(ep, camera="top")


def test_a_damaged_frames_entry_is_refused_on_load(saved, tmp_path):
    import shutil

    _, _, out = saved
    bad = tmp_path / "modules"
    shutil.copytree(out, bad)
    cfg = json.loads((bad / "config.json").read_text())
    cfg["config"]["frames"] = {"eye": {"hidden": 4, "n_actions": 3}}
    (bad / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(CheckpointError):
        trained.load(bad)
