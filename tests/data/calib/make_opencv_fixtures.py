"""Writes the OpenCV FileStorage fixtures of tests/calib_import.rs with the
OpenCV of the running Python, as `calibrateCamera` users save them (the
keys of OpenCV's calibration sample): opencvN.yaml and opencvN.xml, N the
OpenCV major version. The committed files come from OpenCV 4.14.0
(opencv-python-headless) and 5.0.0 (the project venv).

The camera is EuRoC MAV's cam0 (Kalibr pinhole-radtan); the Kalibr and ROS
fixtures beside these describe the same camera.
"""

import cv2
import numpy as np

K = np.array(
    [[458.654, 0.0, 367.215], [0.0, 457.296, 248.375], [0.0, 0.0, 1.0]],
    dtype=np.float64,
)
D = np.array(
    [[-0.28340811], [0.07395907], [0.00019359], [1.76187114e-05], [0.0]],
    dtype=np.float64,
)

major = cv2.__version__.split(".")[0]
for ext in ("yaml", "xml"):
    fs = cv2.FileStorage(f"opencv{major}.{ext}", cv2.FILE_STORAGE_WRITE)
    fs.write("calibration_time", "Sat Jun  1 10:00:00 2024")
    fs.write("nr_of_frames", 25)
    fs.write("image_width", 752)
    fs.write("image_height", 480)
    fs.write("board_width", 9)
    fs.write("board_height", 6)
    fs.write("square_size", 0.025)
    fs.write("flags", 0)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", D)
    fs.write("avg_reprojection_error", 0.1874)
    fs.write("per_view_reprojection_errors", np.array([[0.18], [0.19]], dtype=np.float32))
    fs.write("extrinsic_parameters", np.zeros((2, 6), dtype=np.float64))
    fs.write("image_points", np.zeros((2, 3, 2), dtype=np.float32))
    fs.release()
