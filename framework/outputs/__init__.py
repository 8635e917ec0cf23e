"""What a run produces for people: frames of a run, videos, camera paths, PLY, reports."""
