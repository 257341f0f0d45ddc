"""File formats at the edges of the pipeline: frames, priors, results."""
