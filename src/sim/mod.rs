//! Scene simulator: seeded intersection world, LiDAR and satellite layers, fisheye frames, GPS.
