"""Geometry every layer shares: the projection and distortion functions (:mod:`.camera`), the camera model classes
with analytic derivatives (:mod:`.models`), SO(3) maps, relative poses of a rig's cameras (:mod:`.poses`), the
inverses of the normal matrices and the paper's accuracy metrics.

It imports nothing of the stages.
"""
