"""Campaigns of runs: parameter sweeps (:mod:`.sweep`), where their points run
(:mod:`.distribute`: in process, a Dask LocalCluster or a scheduler), the ``expect:``
verdicts with JUnit output (:mod:`.expect`), and design: requirements in, the cheapest
configuration out (:mod:`.design`, with the fast predictors of :mod:`.predict`). A new
campaign command starts here."""
