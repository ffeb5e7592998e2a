//! pinc as a MAVLink participant next to an ArduSub autopilot: the connection address
//! ([`url`]), the link with its receive thread, ground-station heartbeat and commands
//! ([`link`]), the vehicle's state rebuilt from the autopilot's messages ([`state`]), the
//! MCAP recording of a session ([`record`]), the body input turned into commands
//! ([`command`]), the safety watchdog ([`safety`]) and a command session driven by the
//! state's arrival ([`drive`]); the autopilot's firmware and parameters checked (and set) before
//! a dive ([`check`]). `docs/VEHICLE.md` is the user's guide.

pub mod autopilot_estimate;
pub mod check;
pub mod cli;
pub mod command;
pub mod depth_band;
pub mod drive;
pub mod ground_station;
#[allow(clippy::module_inception)]
pub mod link;
pub mod outputs;
pub mod params;
pub mod record;
pub mod safety;
pub mod session;
pub mod signing;
pub mod state;
pub mod url;

pub use autopilot_estimate::{EkfStatus, HeadingReference};
pub use command::{Command, CommandError, CommandWay, Commander};
pub use depth_band::{BandHeave, DepthBand};
pub use drive::{Drive, DriveSettings, Fresh, Note, Sent, Stopped};
pub use ground_station::GroundStationPlace;
pub use link::{Autopilot, LinkConfig, LinkError, Received, SubMode, VehicleLink};
pub use outputs::{OutputFunctions, WayRefused};
pub use params::{Params, read_params, write_param};
pub use record::{InputsFromOutputs, RecordError, RecordStats, Recorder};
pub use safety::{Safety, SafetyLimits, SensorWatch, Trigger};
pub use signing::{SigningError, SigningKey};
pub use state::{Capability, Part, PartStatus, RawState, StateAssembler, StateConfig};
pub use url::{LinkAddress, UrlError};
