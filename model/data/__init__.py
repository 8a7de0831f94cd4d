"""Training data: the index of takes, splits, the preprocessed-data cache, procedural motion, where the data lives."""
