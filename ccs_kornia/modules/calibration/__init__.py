"""Calibration stage: homographies, closed-form initialisations, the batched Levenberg–Marquardt core and
the camera models it refines."""
