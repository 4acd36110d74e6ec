"""The base layer: value rules, atomic files, folder locks and interrupts, sealed checkpoints.
"""
