"""The simulated world: the iCub arm scene, physics backends, the env, tasks, placements,
vision and rendering.
"""
