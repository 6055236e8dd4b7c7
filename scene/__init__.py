"""The scene: terrain tiles (`terrain`; procedural, the seed paper's `classes`, GeoTIFF
in any CRS: `geotiff`), clouds, calibration `targets` (the slanted square), the host-side ray
geometry (`pinhole`), the main imager's image as the camera forms it (`strip`), and the
Mitsuba kernel layer that renders them (`kernel`, the only module of imcsim that imports
mitsuba / drjit; its variant chosen by `variant`). Importing this package imports neither.
"""

#: the seed paper's scene classes (:mod:`scene.classes`)
SCENE_CLASSES = ("urban", "rural", "mountain", "waves", "calm_water")
#: every kind of tile a scenario can name: the generic procedural tile, the classes, a GeoTIFF
SCENE_KINDS = ("procedural", *SCENE_CLASSES, "geotiff")
