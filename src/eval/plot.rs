//! Pictures of an evaluation: placeholder replaced below.
