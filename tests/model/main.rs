//! The `.pinc` file: every kind of corruption refused with a typed error, round trips, and
//! the shipped models' quality margins.

#[path = "../common/mod.rs"]
mod common;

mod errors;
mod round_trip;
mod shipped;
