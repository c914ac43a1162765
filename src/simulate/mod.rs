//! Synthetic sequences: scene, renderer, IMU synthesis, EuRoC output.
