//! The controller in closed loop against the simulated vehicle, and its MCAP log.

#[path = "../common/mod.rs"]
mod common;

mod closed_loop;
mod four_axis;
mod mcap_log;
mod pilot;
mod riccati;
