//! Whole-scene tests (small preset).
