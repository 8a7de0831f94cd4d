"""Running a trained bundle: bundles, the engine and its batch, the per-frame step, the output pipeline (output/), style codes."""
