//! The burn trainer: losses and tangents against independent computations, agreement with
//! the frozen runtime, and a smoke run.

#[path = "../common/mod.rs"]
mod common;

mod agreement;
mod hybrid;
mod losses;
mod smoke;
