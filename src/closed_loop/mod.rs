//! The closed loop: the analytic vehicle as the plant (inputs held over each sample, RK4
//! with 16 sub-steps), an [`Mpc`](crate::mpc::Mpc) on any model, the tracking scenarios,
//! the summary of a run (tracking errors, overshoot, settling, solver timing, fallbacks,
//! bound violations) and its MCAP log for Foxglove, also served live over Foxglove's WebSocket
//! protocol with feature `live-view`.

pub mod campaign;
#[cfg(feature = "live-view")]
pub mod live_view;
mod log;
pub mod monte_carlo;
pub mod path_plan;
mod run;
mod scenario;
mod summary;
mod track;

pub use log::{CHUNK_INTERVAL_NS, Level, LogError, LogStats, McapLog, RunInfo, file_sha256};
pub use run::{Sample, run, run_on, run_with};
pub use scenario::{FOUR_AXIS_CURRENT, Plant, ReferenceFileError, Scenario};
pub use summary::{
    HOLD_LEAD_S, HOLD_SETTLE_S, HorizontalFigures, PATH_FINISHED_WITHIN_M, STATION_SETTLE_S, Summary,
    horizontal_figures, summarise,
};
pub use track::Track;
