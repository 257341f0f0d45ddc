"""Pipeline orchestration: inputs -> 2D tracks -> world-centric 3D -> result files."""
