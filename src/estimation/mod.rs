//! State estimation on the model: an extended Kalman filter whose process model is the
//! controller's own ([`ekf`]), the measurements a vehicle gives and their noise
//! ([`measurement`]), the filter fed in time as a controller or a log replay feeds it
//! ([`estimator`]), where its horizontal estimate stands: measured, dead reckoned or lost
//! ([`navigation`]), what its innovations say of the model ([`health`]: the adaptation of its
//! process noise, the live stop on a lost vehicle), ArduSub's MAVLink messages turned into
//! measurements ([`mavlink`]), a smoother for recorded logs ([`smoother`]) and a recorded log
//! replayed through the filter ([`replay`]), and a recorded dataset's windows started from
//! the filter's state rather than the recorded one ([`window_starts`]).
//!
//! A stock BlueROV2 measures depth (pressure), heading and yaw rate, and knows the thrust it
//! commands; with the model that is enough to estimate its body velocities, which the MPC
//! needs. `docs/MODEL.md` (section "State estimation") gives the equations.

pub mod ekf;
pub mod estimator;
pub mod health;
#[cfg(feature = "tools")]
pub mod mavlink;
pub mod measurement;
pub mod navigation;
#[cfg(feature = "tools")]
pub mod replay;
pub mod smoother;
#[cfg(feature = "data")]
pub mod window_starts;

pub use ekf::{Ekf, Estimate, FilterCounts, NE, Update};
pub use estimator::{Estimator, HORIZONTAL_FRESH_S, MAX_FIX_LATENCY_S};
pub use health::{Health, Lost, Sensor};
pub use measurement::{Measurement, NoiseSettings, white_noise_std};
pub use navigation::{DEFAULT_DEAD_RECKONING_BOUND_M, Navigation};
