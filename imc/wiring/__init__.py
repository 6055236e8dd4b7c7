"""One run's wiring: models and loop blocks built from a scenario (:mod:`.build`), its size
estimate (:mod:`.budget`) and the correlator device's budget (:mod:`.device_budget`), what a
run is told before it starts (:mod:`.advisories`), the rendered tracker plant
(:mod:`.rendered_plant`), the truth (:mod:`.truth`), the main imager's blur from the truth
(:mod:`.blur`), its rendered study, product and ground processing (:mod:`.product`), the
product as a Level-1 product (RPCs, orthorectification, geolocation in metres:
:mod:`.level1`), the record's links (:mod:`.links`) and the ground's restitution of it
(:mod:`.restitution`), ground control from a reference orthoimage (:mod:`.orthocontrol`),
named random streams (:mod:`.streams`), checkpoints (:mod:`.checkpoint`) and the device
emulator's run (:mod:`.emulator`). Computes results and returns them labelled; the files,
figures and report are written by imc.outputs; imports nothing from outputs, workflow or
studies."""
