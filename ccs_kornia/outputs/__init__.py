"""What the commands write: the JSON records of a calibration and of a rig, the HTML reports, the calibration file
read back, and the files other tools load (OpenCV YAML, ROS ``camera_info``, Kalibr's camchain).

Above the pipeline (records are built from its results), below the commands.
"""
