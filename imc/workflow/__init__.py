"""Campaigns of runs: parameter sweeps (:mod:`.sweep`), where their points run
(:mod:`.distribute`: in process, a Dask LocalCluster or a scheduler) and the ``expect:``
verdicts with JUnit output (:mod:`.expect`). A new campaign command starts here."""
