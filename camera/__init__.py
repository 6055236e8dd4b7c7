"""The camera: optics and focal-plane geometry, exact projection, predicted image motion,
the imagers and how they sample, the detector and the exposure chain.

- `geometry`: the pinhole focal plane and exact projection, float64;
- `motion`: the camera model (orbit + attitude + Earth rotation -> poses, image motion) and
  the one ray-terrain intersection (:func:`camera.motion.intersect_terrain`);
- `imager`: the main imager kinds as classes (frame, TDI; registry ``IMAGERS``): kind,
  integration time, sampling, charge motion, product sign;
- `sampling`: the instants and footprint offsets of a TDI line or a frame exposure;
- `linescan`: the imager's camera (built once, :func:`camera.linescan.imager_camera`) and the
  truth of where each rendered line's content sits on the nominal grid;
- `optics`: telescope MTF and PSF; `sensor`: photo-electrons -> DN with noise;
- `exposure`: the one exposure chain, radiance -> optics -> electrons -> DN.

Pixel coordinates are (row, col) with integer values at pixel centres; image motion is in
pixels with the sign convention of docs/conventions.md.
"""

from camera.geometry import BODY_FROM_CAM, FocalPlane, Pose, project
from camera.motion import CameraModel
from camera.sensor import SensorModel

__all__ = ["BODY_FROM_CAM", "CameraModel", "FocalPlane", "Pose", "SensorModel", "project"]
