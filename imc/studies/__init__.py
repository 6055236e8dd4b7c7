"""The studies behind the figures in docs/: the seed paper's Table 2 (:mod:`.table2`), its
texture-robustness map (:mod:`.texture_map`) and airborne flight test (:mod:`.flight`), and
the correlator against its bounds and its peers, scikit-image and OpenCV
(:mod:`.correlator_peers`). Each builds what it needs from the stages and the wiring; a new
study is a module here and a script in benchmarks/."""
