"""The output steps: what happens to the network's frames before they leave (listed in
:mod:`model.inference.output.pipeline`)."""
