"""The iCub arm scene: robot from ``icub-models``, table and three objects, built with MjSpec.

The model is built once per process (``model()`` is cached). Everything that varies between
episodes -- which shape stands where, the arm's start pose -- is *data* (qpos), never model
structure, so one compiled model (and one MJX ``put_model``) serves every layout.
"""

from __future__ import annotations

import functools
import itertools
import json
import pathlib
from typing import NamedTuple

import mujoco
import numpy as np

from grounding_jax.sim import tasks

ASSETS = pathlib.Path(__file__).resolve().parent / "assets"  # package data (assets/ links here)
SCENE_XML = ASSETS / "table_scene.xml"
POINTING_JSON = ASSETS / "pointing_configs.json"
URDF_ROBOT = "iCubGazeboV2_5"

JOINT_NAMES = ("r_shoulder_pitch", "r_shoulder_roll", "r_shoulder_yaw", "r_elbow")
#: Joint limits the paper uses for eq. 1, degrees (pitch, roll, yaw, elbow).
PAPER_LIMITS_DEG = np.array([[-95.0, 90.0], [0.0, 161.0], [-37.0, 100.0], [-6.0, 106.0]])
#: Start pose of every episode (the URDF zero pose puts the hand inside the table).
HOME_POSE_DEG = np.array([-60.0, 110.0, 67.0, 97.0])

ACTIONS, POSITIONS, SHAPES, COLOURS = tasks.ACTIONS, tasks.POSITIONS, tasks.SHAPES, tasks.COLOURS
# Saturated and dark enough that every face is well below the white table in grey (vision).
COLOUR_RGBA = {
    "red": (0.75, 0.08, 0.08, 1.0), "green": (0.08, 0.5, 0.08, 1.0), "blue": (0.1, 0.15, 0.75, 1.0)
}

#: Object centres on the table, one per position (robot frame: x backward, y right, z up).
TABLE_Z = -0.05
OBJECT_HALF = 0.025
OBJECT_X = -0.24
OBJECT_Y = (0.09, 0.20, 0.31)  # left, middle, right: 0.11 m apart, right-hand side
#: Layouts: 6 shape orders x 6 colour orders. ``LAYOUTS[i] = (shape_order, colour_order)``,
#: each order a tuple giving the shape/colour at left, middle, right.
SHAPE_ORDERS = tuple(itertools.permutations(SHAPES))
COLOUR_ORDERS = tuple(itertools.permutations(COLOURS))
LAYOUTS = tuple(itertools.product(SHAPE_ORDERS, COLOUR_ORDERS))

# Hand geometry in the URDF's r_hand frame (fingers along -x, palm facing -y), metres.
_PALM_SITE_POS = (-0.05, -0.020, 0.015)
_HAND_CAPSULES = {
    "palm_col": ((-0.012, 0.006, 0.012), (-0.07, 0.006, 0.012), 0.024),
    "fingers_col": ((-0.075, 0.004, 0.03), (-0.14, 0.004, 0.03), 0.013),
}
_FOREARM_CAPSULE = ((0.01, 0.0, 0.005), (-0.10, 0.0, 0.02), 0.033)
#: The arm's collision geoms (the only robot geoms that collide).
ARM_CAPSULES = (*_HAND_CAPSULES, "forearm_col")
# Right eye relative to the head link's origin (world axes at the fixed head pose), metres.
_EYE_OFFSET = (-0.07, 0.034, 0.06)
_EYE_FOVY = 50.0

# Position servos on the arm joints: stiff enough that a commanded change of a few degrees is
# ~87% reached within one RL step (10 substeps x 5 ms) and all of it in two, overshoot < 3%.
ACTUATOR_KP = 500.0
JOINT_DAMPING = 15.0
JOINT_ARMATURE = 0.02

# Geom groups (for rendering): 0 scene, 2 robot visual meshes, 3 collision-only helpers.
GROUP_ROBOT_VISUAL = 2
GROUP_COLLISION = 3

# Bits of contype/conaffinity (see assets/table_scene.xml).
_BIT_TABLE, _BIT_ARM, _BIT_OBJECT = 1, 2, 4
_PREFIX = "icub__"


class SceneIndex(NamedTuple):
    """Addresses inside the compiled model that the env needs (all plain ints/arrays)."""

    nq: int
    nv: int
    nu: int
    arm_qpos: np.ndarray  # qpos addresses of the 4 arm joints
    arm_dof: np.ndarray
    object_qpos: np.ndarray  # [3 shapes, 7] free-joint qpos addresses (box, cylinder, sphere)
    object_dof: np.ndarray  # [3, 6]
    sensor_palm_pos: np.ndarray  # sensordata addresses of the palm site position (3)
    sensor_palm_touch: int  # palm touch sensor (normal force, N)
    sensor_contact: np.ndarray  # [3 shapes, 3 arm capsules]: contacts found per pair
    joint_range: np.ndarray  # [4, 2] model limits, radians
    nsensordata: int


def icub_share_dir() -> pathlib.Path:
    """The folder that ``package://iCub/`` refers to in the icub-models URDFs."""
    import icub_models

    robots = pathlib.Path(icub_models.get_models_path())  # .../share/iCub/robots
    return robots.parent


def _robot_spec() -> mujoco.MjSpec:
    """The iCub URDF reduced to the four right-arm joints, meshes visual only."""
    share = icub_share_dir()
    urdf = share / "robots" / URDF_ROBOT / "model.urdf"
    if not urdf.exists():
        raise FileNotFoundError(f"icub-models has no {URDF_ROBOT} URDF at {urdf}")
    text = urdf.read_text().replace("package://iCub/", f"{share}/")
    spec = mujoco.MjSpec.from_string(text)
    spec.compiler.fusestatic = True
    for body in ("r_hip_1", "l_hip_1", "l_shoulder_1"):
        spec.delete(spec.body(body))
    for joint in list(spec.joints):
        if joint.name not in JOINT_NAMES:
            spec.delete(joint)
    for geom in spec.geoms:
        geom.contype = 0
        geom.conaffinity = 0
        geom.group = GROUP_ROBOT_VISUAL
        geom.rgba = (0.85, 0.85, 0.88, 1.0)

    def capsule(body: str, name: str, a, b, radius: float) -> None:
        g = spec.body(body).add_geom()
        g.name = name
        g.type = mujoco.mjtGeom.mjGEOM_CAPSULE
        g.fromto = np.concatenate([a, b])
        g.size = (radius, 0, 0)
        g.contype = _BIT_ARM
        g.conaffinity = _BIT_TABLE | _BIT_OBJECT
        g.condim = 3
        g.friction = (0.8, 0.005, 0.0001)
        g.group = GROUP_COLLISION
        g.mass = 0.0  # visual meshes' inertials from the URDF carry the mass
        g.density = 0.0

    for name, (a, b, r) in _HAND_CAPSULES.items():
        capsule("r_hand", name, a, b, r)
    capsule("r_forearm", "forearm_col", *_FOREARM_CAPSULE)
    site = spec.body("r_hand").add_site()
    site.name = "palm"
    site.type = mujoco.mjtGeom.mjGEOM_BOX
    site.pos = _PALM_SITE_POS
    site.size = (0.035, 0.012, 0.03)
    site.rgba = (1, 0.5, 0, 0.3)

    # Camera in the right eye, looking at the objects (iCub eyes ~0.07 m in front of the neck).
    return spec


#: the third-person camera: in front of the robot and to its right, looking at arm and objects
OBSERVER_POS = (-0.78, 0.42, 0.30)
OBSERVER_TARGET = (-0.10, 0.12, 0.04)


def _look_at_xyaxes(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """MuJoCo camera ``xyaxes`` (world) for a camera at ``eye`` looking at ``target``."""
    fwd = target - eye
    fwd = fwd / np.linalg.norm(fwd)
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(fwd, up)
    x /= np.linalg.norm(x)
    y = np.cross(x, fwd)
    return np.concatenate([x, y])


def build_spec() -> mujoco.MjSpec:
    """Build the full scene spec (robot + table + objects + actuators + sensors).

    Returns:
        An uncompiled ``mujoco.MjSpec``; ``model()`` compiles and caches it.
    """
    scene = mujoco.MjSpec.from_file(str(SCENE_XML))
    robot = _robot_spec()
    # Attach under a prefix (an empty one makes MuJoCo warn and write MUJOCO_LOG.TXT), then
    # give the robot's elements back their URDF names.
    scene.attach(robot, prefix=_PREFIX, frame=scene.worldbody.add_frame())
    for group in (scene.bodies, scene.joints, scene.geoms, scene.sites, scene.cameras):
        for el in group:
            if el.name.startswith(_PREFIX):
                el.name = el.name[len(_PREFIX):]

    scene.compiler.fusestatic = True
    stack = [scene.body("r_shoulder_1")]
    while stack:  # gravity compensation on the whole arm: the servos hold it without sag
        body = stack.pop()
        body.gravcomp = 1.0
        stack.extend(body.bodies)
    for name in JOINT_NAMES:
        j = scene.joint(name)
        j.damping = [JOINT_DAMPING, 0.0, 0.0]
        j.armature = JOINT_ARMATURE
        act = scene.add_actuator()
        act.name = name
        act.target = name
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_position(kp=ACTUATOR_KP)
        act.ctrlrange = j.range
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE

    s = scene.add_sensor()
    s.name = "palm_pos"
    s.type = mujoco.mjtSensor.mjSENS_FRAMEPOS
    s.objtype = mujoco.mjtObj.mjOBJ_SITE
    s.objname = "palm"
    s = scene.add_sensor()
    s.name = "palm_touch"
    s.type = mujoco.mjtSensor.mjSENS_TOUCH
    s.objtype = mujoco.mjtObj.mjOBJ_SITE
    s.objname = "palm"
    # Hand-object contacts, one sensor per (object, arm capsule) pair: MJX matches contact
    # sensors by geom only (not body or subtree).
    for shape in SHAPES:
        for capsule_name in ARM_CAPSULES:
            s = scene.add_sensor()
            s.name = f"contact_{shape}_{capsule_name}"
            s.type = mujoco.mjtSensor.mjSENS_CONTACT
            s.objtype = mujoco.mjtObj.mjOBJ_GEOM
            s.objname = f"{shape}_geom"
            s.reftype = mujoco.mjtObj.mjOBJ_GEOM
            s.refname = capsule_name
            s.intprm = [1, 1, 1]  # data="found", reduce="mindist", num=1

    # The eye camera sits in the (fixed) head; the head is fused into the world at compile time,
    # so place the camera in world coordinates from the head's pose in an unfused compile.
    scene.compiler.fusestatic = False
    m = scene.compile()
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    eye = d.xpos[m.body("head").id] + np.asarray(_EYE_OFFSET)
    scene.compiler.fusestatic = True
    target = np.array([OBJECT_X, OBJECT_Y[1], TABLE_Z + OBJECT_HALF])
    cam = scene.worldbody.add_camera()
    cam.name = "eye"
    cam.fovy = _EYE_FOVY
    cam.pos = eye
    cam.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
    cam.alt.xyaxes = _look_at_xyaxes(eye, target)
    # A third-person camera facing the robot across the table, for people (videos); the robot
    # never sees through it. Cameras add nothing to the physics.
    cam = scene.worldbody.add_camera()
    cam.name = "observer"
    cam.fovy = 50.0
    cam.pos = np.asarray(OBSERVER_POS)
    cam.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
    cam.alt.xyaxes = _look_at_xyaxes(cam.pos, np.asarray(OBSERVER_TARGET))
    return scene


@functools.cache
def model() -> mujoco.MjModel:
    """The compiled scene model, built once per process. Do not mutate it."""
    return build_spec().compile()


@functools.cache
def index() -> SceneIndex:
    """Addresses of joints, objects and sensors in ``model()``."""
    m = model()
    arm_qpos = np.array([m.jnt_qposadr[m.joint(n).id] for n in JOINT_NAMES])
    arm_dof = np.array([m.jnt_dofadr[m.joint(n).id] for n in JOINT_NAMES])
    obj_qpos = np.array([m.jnt_qposadr[m.joint(f"{s}_joint").id] + np.arange(7) for s in SHAPES])
    obj_dof = np.array([m.jnt_dofadr[m.joint(f"{s}_joint").id] + np.arange(6) for s in SHAPES])
    adr = {m.sensor(i).name: int(m.sensor_adr[i]) for i in range(m.nsensor)}
    return SceneIndex(
        nq=m.nq, nv=m.nv, nu=m.nu,
        arm_qpos=arm_qpos, arm_dof=arm_dof, object_qpos=obj_qpos, object_dof=obj_dof,
        sensor_palm_pos=adr["palm_pos"] + np.arange(3),
        sensor_palm_touch=adr["palm_touch"],
        sensor_contact=np.array([[adr[f"contact_{s}_{c}"] for c in ARM_CAPSULES]
                                 for s in SHAPES]),
        joint_range=m.jnt_range[[m.joint(n).id for n in JOINT_NAMES]].copy(),
        nsensordata=m.nsensordata,
    )


def object_positions() -> np.ndarray:
    """Resting centre of an object at each position, ``[3 positions, 3]`` (metres)."""
    return np.array([[OBJECT_X, y, TABLE_Z + OBJECT_HALF] for y in OBJECT_Y])


def layout_shape_slots() -> np.ndarray:
    """``[36 layouts, 3 shapes]``: the position index (0 L, 1 M, 2 R) of each shape."""
    out = np.zeros((len(LAYOUTS), len(SHAPES)), dtype=np.int32)
    for i, (shape_order, _) in enumerate(LAYOUTS):
        for pos, shape in enumerate(shape_order):
            out[i, SHAPES.index(shape)] = pos
    return out


def layout_name(i: int) -> str:
    """Human-readable layout, e.g. ``'box/red cylinder/green sphere/blue'`` (left to right)."""
    shapes, colours = LAYOUTS[i]
    return " ".join(f"{s}/{c}" for s, c in zip(shapes, colours, strict=True))


def paint_layout(m: mujoco.MjModel, layout: int) -> None:
    """Colour the objects of (a private copy of) the model as in ``layout`` (0..35): colour
    is data, not model structure, so the renderers paint it in."""
    shapes, colours = LAYOUTS[layout]
    for shape, colour in zip(shapes, colours, strict=True):
        m.geom_rgba[m.geom(f"{shape}_geom").id] = COLOUR_RGBA[colour]


def home_qpos() -> np.ndarray:
    """Full ``qpos`` with the arm at home and the objects of layout 0 at rest."""
    m, idx = model(), index()
    q = m.qpos0.copy()
    q[idx.arm_qpos] = np.radians(HOME_POSE_DEG)
    place_objects(q, 0)
    return q


def place_objects(qpos: np.ndarray, layout: int, placement: np.ndarray | None = None
                  ) -> np.ndarray:
    """Write the resting object poses of ``layout`` into ``qpos`` (in place; also returned):
    in the paper's slots, or in those of a ``placement`` ``[3, 3]`` (x, y, yaw per slot; see
    `grounding_jax.sim.placement`)."""
    idx = index()
    pos = object_positions()
    for shape, slot in enumerate(layout_shape_slots()[layout]):
        if placement is None:
            qpos[idx.object_qpos[shape, :3]] = pos[slot]
            qpos[idx.object_qpos[shape, 3:]] = (1.0, 0.0, 0.0, 0.0)
        else:
            x, y, yaw = np.asarray(placement, float)[slot]
            qpos[idx.object_qpos[shape, :3]] = (x, y, TABLE_Z + OBJECT_HALF)
            qpos[idx.object_qpos[shape, 3:]] = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))
    return qpos


def pointing_configs() -> np.ndarray:
    """Stored pointing joint configurations ``[3 positions, 4]`` in radians (see assets/)."""
    data = json.loads(POINTING_JSON.read_text())
    return np.radians(np.array([data["positions"][p]["joints_deg"] for p in POSITIONS]))
