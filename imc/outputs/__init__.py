"""What a run writes: metrics.json, tracks.csv and blur arrays (:mod:`.report`), the figures
(:mod:`.figures`), report.html (:mod:`.htmlreport`), the Rerun recording
(:mod:`.rerun_log`) and the loop study (:mod:`.loopplot`). A new figure goes in
:mod:`.figures`; reads the wiring's results, never runs a scenario."""
