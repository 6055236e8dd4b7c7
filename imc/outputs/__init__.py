"""What a run writes: the metrics, tracks.csv and series.npz (:mod:`.report`), the figures
(:mod:`.figures`), report.html (:mod:`.htmlreport`), the Rerun recording
(:mod:`.rerun_log`), the loop study (:mod:`.loopplot`), the main imager's product files
(:mod:`.product_files`) and its quicklook, report section and recording
(:mod:`.product_report`); where the drawing and recording
run, inline or on a helper process (:mod:`.jobs`). A new figure goes in :mod:`.figures`;
reads the wiring's results, never runs a scenario."""
