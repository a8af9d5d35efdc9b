"""What a person watches: Prometheus metrics, the progress line, the replay report, the run's tallies."""
