"""One module per arrow of the data flow: ingest, segment, fit, track, evaluate; and the demo that runs them
all."""
