"""Optics and focal-plane geometry, exact projection, predicted image motion, sensor model.

Pixel coordinates are (row, col) with integer values at pixel centres; image motion is in
pixels with the sign convention of docs/conventions.md.
"""

from camera.geometry import BODY_FROM_CAM, FocalPlane, Pose, project
from camera.motion import CameraModel
from camera.sensor import SensorModel

__all__ = ["BODY_FROM_CAM", "CameraModel", "FocalPlane", "Pose", "SensorModel", "project"]
