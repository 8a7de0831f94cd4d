"""Training recipes: one module per stage, sharing the loop in :mod:`model.train.loop`."""
