"""The simulation engine: state pytrees, boundaries, neighbour lists, pair
interactions, hard collisions, integrators, the compiled step and its runs
(`Simulator`), checkpoints and batched ensembles. It knows nothing of the
papers' protocols."""
