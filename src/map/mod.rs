//! Map tiles: georeferenced grids and layers (pure model) and the on-disk tile cache (I/O shell).
