"""The trained robot: the three modules together (``Robot``), saved, sealed and loaded.
"""
