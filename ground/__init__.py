"""Ground processing of the main imager's product, after compensation in the data flow.

ground/ owns what happens to the main imager's strip (or frame) once it is on the ground:

* ``ground.record``: the per-line image-motion model from the motion record the loop received
  (interpolated in time, averaged over each line's integration window), and the same from a
  perfect record (the truth) to separate the record's own error from interpolation;
* ``ground.network``: the motion record solved as a network of pair measurements (every
  link of every baseline) by sparse weighted least squares with its covariance, per-frame
  noise shared by a frame's links and each frame's noise over the pixels its links share
  (generalised least squares), a two-sided smoother whose prior is estimated from the
  record itself, and the geometry metrics per axis after a constant and after an affine;
* ``ground.aiding``: a gyro's error model, its simulated readings and its relative angles
  between frames, and absolute fixes (ground control, a star tracker), fused in that solve;
* ``ground.blend``: stage + ground never worse than the stage alone, a per-axis, per-band
  (crossover) blend of the ground's estimates of the stage's residual;
* ``ground.rectify``: geometric rectification, the strip resampled onto the nominal
  (motion-free) line/column grid from per-line (or field-dependent) offsets, and the geometric
  error of an estimated offset against the true one;
* ``ground.restore``: the residual-motion PSF and its removal by deconvolution
  (scikit-image), space-variant in runs of lines;
* ``ground.rpc``: RPC00B coefficients (the Level-1 product's replacement sensor model),
  fitted by least squares to the geometry the ground knows, evaluated ground -> image and
  inverted image -> ground;
* ``ground.ortho``: orthorectification through GDAL's RPC transformer with a DEM of heights
  above the ellipsoid (rasterio), and the geolocation figures: CE90, relative accuracy,
  misregistration by phase correlation;
* ``ground.quality``: image-quality figures of a product: ISO 12233 slanted-edge MTF, RER,
  edge overshoot, noise gain, SNR, NIIRS by GIQE 5 (pyBSM), PSNR and SSIM against the static
  product, and a cross-check of the motion MTF against pyBSM's drift and jitter OTFs.

It renders nothing (no renderer, no scene/), and imports only numpy, scipy, scikit-image,
pyBSM, rasterio (GDAL) and the lower stage compensation/ (tests/test_layout.py). Units are
SI inside; image quantities are in pixels of the main imager.
"""
