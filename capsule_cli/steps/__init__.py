"""Steps: compose the models over tables (sweeps, fits, predictions, comparisons)."""
