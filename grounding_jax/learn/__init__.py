"""The learners: the learner seam, CACLA and the action learner (AL), the target localizers
(TL), the ESN namer (AN) and the SOM.
"""
