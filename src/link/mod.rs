//! pinc as a MAVLink participant next to an ArduSub autopilot: the connection address
//! ([`url`]), the link with its receive thread, ground-station heartbeat and commands
//! ([`link`]), the vehicle's state rebuilt from the autopilot's messages ([`state`]), and the
//! MCAP recording of a session ([`record`]). `docs/VEHICLE.md` is the user's guide.

#[allow(clippy::module_inception)]
pub mod link;
pub mod record;
pub mod state;
pub mod url;

pub use link::{Autopilot, LinkConfig, LinkError, Received, SubMode, VehicleLink};
pub use record::{RecordError, RecordStats, Recorder};
pub use state::{Capability, Part, PartStatus, StateConfig, StateEstimate, StateEstimator};
pub use url::{LinkAddress, UrlError};
