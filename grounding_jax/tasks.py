"""The task vocabulary, in one place: actions, positions, target words, and the layout of the
actor's observation and action. The env, the learner's network sizes, the ESN's output size
and the AN take their sizes from here.

Observation (``OBS_SIZE`` = 11): the 4 arm joints (scaled to [-1, 1]), the touch bit, the
action one-hot, the position one-hot. Action (``ACTION_SIZE`` = 4): the change of the 4 scaled
joints.
"""

from __future__ import annotations

ACTIONS = ("point", "touch", "push")
POSITIONS = ("left", "middle", "right")
SHAPES = ("box", "cylinder", "sphere")
COLOURS = ("red", "green", "blue")
#: the words that name a target: a shape or a colour
TARGET_WORDS = (*SHAPES, *COLOURS)

N_JOINTS = 4
N_ACTIONS = len(ACTIONS)
N_POSITIONS = len(POSITIONS)
N_WORDS = len(TARGET_WORDS)

#: where each part of the observation lies
OBS_JOINTS = slice(0, N_JOINTS)
OBS_TOUCH = N_JOINTS
OBS_ACTION = slice(N_JOINTS + 1, N_JOINTS + 1 + N_ACTIONS)
OBS_POSITION = slice(OBS_ACTION.stop, OBS_ACTION.stop + N_POSITIONS)
OBS_SIZE = OBS_POSITION.stop
ACTION_SIZE = N_JOINTS
#: the AN's outputs: one unit per action word, then one per target word
SENTENCE_SIZE = N_ACTIONS + N_WORDS
