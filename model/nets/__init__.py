"""The networks: the pose state they read and write, the phase model, the manifold, the sampler, the style classifier."""
