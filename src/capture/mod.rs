//! Frame capture (I/O shell): V4L2, Aravis and file sources, temporal median.
