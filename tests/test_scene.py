"""The scene: structure, stored pointing poses, layouts."""

from __future__ import annotations

import importlib.util
import json
import pathlib

import mujoco
import numpy as np
import pytest

from grounding_jax.sim import ik, scene


def test_exactly_four_actuated_arm_joints():
    m = scene.model()
    assert m.nu == 4
    actuated = [m.joint(m.actuator_trnid[i, 0]).name for i in range(m.nu)]
    assert actuated == list(scene.JOINT_NAMES)
    hinge = [m.joint(i).name for i in range(m.njnt) if m.jnt_type[i] == mujoco.mjtJoint.mjJNT_HINGE]
    assert hinge == list(scene.JOINT_NAMES)
    free = [m.joint(i).name for i in range(m.njnt) if m.jnt_type[i] == mujoco.mjtJoint.mjJNT_FREE]
    assert free == [f"{s}_joint" for s in scene.SHAPES]


def test_robot_meshes_are_visual_only_and_capsules_collide():
    m = scene.model()
    meshes = m.geom_type == mujoco.mjtGeom.mjGEOM_MESH
    assert meshes.sum() > 5
    assert not m.geom_contype[meshes].any() and not m.geom_conaffinity[meshes].any()
    for name in scene.ARM_CAPSULES:
        g = m.geom(name)
        assert m.geom_type[g.id] == mujoco.mjtGeom.mjGEOM_CAPSULE
        assert m.geom_contype[g.id] != 0


def test_objects_do_not_collide_with_each_other():
    m = scene.model()
    ids = [m.geom(f"{s}_geom").id for s in scene.SHAPES]
    for a in ids:
        for b in ids:
            if a != b:
                assert not (m.geom_contype[a] & m.geom_conaffinity[b])


def test_36_layouts_are_all_shape_and_colour_orders():
    assert len(scene.LAYOUTS) == 36
    assert len(set(scene.LAYOUTS)) == 36
    slots = scene.layout_shape_slots()
    assert all(sorted(row) == [0, 1, 2] for row in slots)
    # layout 0 is box/cylinder/sphere left to right
    assert scene.layout_name(0).split()[0].startswith("box/")
    np.testing.assert_array_equal(slots[0], [0, 1, 2])


@pytest.mark.parametrize("position", range(3))
def test_pointing_pose_aims_the_palm_at_its_object_from_a_distance(position):
    m = scene.model()
    d = mujoco.MjData(m)
    d.qpos[:] = scene.home_qpos()
    q = scene.pointing_configs()[position]
    palm, normal = ik.palm_ray(q)
    to_obj = scene.object_positions()[position] - palm
    dist = np.linalg.norm(to_obj)
    assert 0.08 <= dist <= 0.15
    assert np.degrees(np.arccos(to_obj @ normal / dist)) < 2.0  # the palm faces the object
    assert palm[2] > scene.TABLE_Z + 0.05
    # clear of every object by >= 4 cm, whatever the layout (shapes differ per position)
    assert ik.clearance(q) >= 0.04 - 1e-4
    for layout in range(0, len(scene.LAYOUTS), 6):
        scene.place_objects(d.qpos, layout)
        d.qpos[scene.index().arm_qpos] = q
        mujoco.mj_forward(m, d)
        assert d.ncon == 0 or all(
            m.geom_contype[d.contact.geom1[i]] & 1 or m.geom_contype[d.contact.geom2[i]] & 1
            for i in range(d.ncon))  # only objects resting on the table
        assert d.sensordata[scene.index().sensor_contact].sum() == 0


def test_pointing_json_matches_what_the_model_gives():
    data = json.loads(scene.POINTING_JSON.read_text())
    for p, name in enumerate(scene.POSITIONS):
        palm, _ = ik.palm_ray(scene.pointing_configs()[p])
        np.testing.assert_allclose(palm, data["positions"][name]["palm_xyz_m"], atol=1e-4)


def test_home_pose_is_free_of_contacts_and_objects_rest():
    m = scene.model()
    d = mujoco.MjData(m)
    d.qpos[:] = scene.home_qpos()
    d.ctrl[:] = np.radians(scene.HOME_POSE_DEG)
    for _ in range(200):  # 1 s
        mujoco.mj_step(m, d)
    idx = scene.index()
    np.testing.assert_allclose(d.qpos[idx.arm_qpos], np.radians(scene.HOME_POSE_DEG), atol=1e-3)
    np.testing.assert_allclose(d.qpos[idx.object_qpos[:, :3]], scene.object_positions(),
                               atol=1e-3)
    assert d.sensordata[idx.sensor_contact].sum() == 0


def test_model_is_built_once_per_process():
    assert scene.model() is scene.model()


def test_eye_camera_sees_the_objects():
    m = scene.model()
    d = mujoco.MjData(m)
    d.qpos[:] = scene.home_qpos()
    mujoco.mj_forward(m, d)
    cam = m.camera("eye").id
    pos, mat = d.cam_xpos[cam], d.cam_xmat[cam].reshape(3, 3)
    half = np.tan(np.radians(m.cam_fovy[cam] / 2))
    for obj in scene.object_positions():
        local = mat.T @ (obj - pos)  # camera looks along -z
        assert local[2] < 0
        assert abs(local[1] / -local[2]) < half  # inside the vertical field of view
        assert abs(local[0] / -local[2]) < half * 4 / 3  # 320x240 aspect


@pytest.mark.parametrize("argv,option", [
    (["--distance", "0.2", "0.1"], "--distance"),
    (["--distance", "0.01", "0.1"], "--distance"),
    (["--clearance", "-1"], "--clearance"),
    (["--path-clearance", "nan"], "--path-clearance"),
])
def test_pointing_pose_settings_are_checked_before_the_search(argv, option, capsys):
    spec = importlib.util.spec_from_file_location(
        "make_pointing_configs",
        pathlib.Path(__file__).parents[1] / "grounding_jax" / "sim" / "assets"
        / "make_pointing_configs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    with pytest.raises(SystemExit) as e:
        mod.main(argv)
    assert e.value.code == 2 and option in capsys.readouterr().err
