//! YEI 3-Space serial IMU: the pure binary codec
//! ([`protocol`], [`commands`]), the device driver that owns the port and a
//! decode thread ([`device`]), and a simulated sensor serving the protocol on
//! a pseudo-terminal for tests ([`simulated`]).

pub mod commands;
pub mod device;
pub mod protocol;
pub mod simulated;
