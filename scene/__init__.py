"""The scene: terrain tiles (procedural, the seed paper's classes, GeoTIFF in any CRS),
clouds, and the Mitsuba kernel layer that renders them (``scene.kernel``, the only module
of imcsim that imports mitsuba / drjit). Importing this package imports neither.
"""

#: the seed paper's scene classes (:mod:`scene.classes`)
SCENE_CLASSES = ("urban", "rural", "mountain", "waves", "calm_water")
#: every kind of tile a scenario can name: the generic procedural tile, the classes, a GeoTIFF
SCENE_KINDS = ("procedural", *SCENE_CLASSES, "geotiff")
