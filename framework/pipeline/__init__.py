"""One module per arrow of the data flow: ingest, plates, segment, fit, track, landmarks, evaluate; a run's
frames, and the step runner the jobs (``mmcsplat.jobs``: the demo, ``mmcsplat run``) and study cells chain
them with."""
