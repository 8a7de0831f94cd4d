"""Running a trained bundle: the engine, bundles, the per-frame steps, arrival, foot lock, output filter, style codes."""
