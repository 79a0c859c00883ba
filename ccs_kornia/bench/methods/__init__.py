"""What the benchmark compares: the corner detectors under test (methods), ``cv2.fisheye.calibrate`` as its users run
it (fisheye_opencv), the frame choices ours is compared with (frame_baselines).
"""
