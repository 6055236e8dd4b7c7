"""One run's wiring: models and loop blocks built from a scenario (:mod:`.build`), its size
estimate (:mod:`.budget`), the rendered tracker plant (:mod:`.rendered_plant`), the truth
(:mod:`.truth`), the main imager's blur study (:mod:`.blur`), named random streams
(:mod:`.streams`), checkpoints (:mod:`.checkpoint`) and the device emulator's run
(:mod:`.emulator`). Writes no report; imports nothing from outputs, workflow or studies."""
