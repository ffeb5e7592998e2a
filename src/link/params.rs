//! The autopilot's parameters, read by name (`PARAM_REQUEST_READ`, answered by
//! `PARAM_VALUE`): what pinc must know of the autopilot's configuration before it commands
//! anything (its outputs, its pilot gain, its compass declination); and the one it changes for a
//! flight (`PARAM_SET`, confirmed by the `PARAM_VALUE` that answers it).

use super::link::{Autopilot, LinkError, Received, VehicleLink};
use mavlink::dialects::ardupilotmega::{MavMessage, MavParamType, PARAM_REQUEST_READ_DATA, PARAM_SET_DATA};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// How often a request still unanswered is sent again (requests and answers may be lost).
const RETRY: Duration = Duration::from_millis(500);

/// Parameters read from the autopilot, by name; a name the autopilot did not answer is absent.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Params {
    values: BTreeMap<String, f64>,
}

impl Params {
    /// Parameters from name-value pairs (tests, a parameter file).
    pub fn from_pairs<'a>(pairs: impl IntoIterator<Item = (&'a str, f64)>) -> Self {
        Self { values: pairs.into_iter().map(|(k, v)| (k.to_string(), v)).collect() }
    }

    /// The value of `name`, if the autopilot answered it.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.values.get(name).copied()
    }

    /// Every value read.
    pub fn all(&self) -> &BTreeMap<String, f64> {
        &self.values
    }
}

/// The text of a `PARAM_VALUE`'s id (up to its first NUL).
fn param_name(id: &[u8]) -> String {
    id.iter().take_while(|b| **b != 0).map(|b| *b as char).collect()
}

/// Reads `names` from the autopilot: each is asked for (again every half second while
/// unanswered) until all are answered or `timeout` passes. Every message received meanwhile
/// goes to `seen`. ArduPilot does not answer a name it does not have: such a name is absent
/// from the result.
///
/// # Errors
/// The link breaks.
pub fn read_params(
    link: &mut VehicleLink,
    autopilot: &Autopilot,
    names: &[String],
    timeout: Duration,
    mut seen: impl FnMut(&Received),
) -> Result<Params, LinkError> {
    let mut params = Params::default();
    let start = Instant::now();
    let mut next_ask = start;
    while names.iter().any(|n| !params.values.contains_key(n)) && start.elapsed() < timeout {
        if Instant::now() >= next_ask {
            for name in names.iter().filter(|n| !params.values.contains_key(*n)) {
                link.send(&MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
                    param_index: -1,
                    target_system: autopilot.system_id,
                    target_component: autopilot.component_id,
                    param_id: name.as_str().into(),
                }))?;
            }
            next_ask = Instant::now() + RETRY;
        }
        let Some(r) = link.recv_timeout(Duration::from_millis(20))? else { continue };
        if let MavMessage::PARAM_VALUE(p) = &r.message
            && r.header.system_id == u32::from(autopilot.system_id)
        {
            let name = param_name(p.param_id.as_slice());
            if names.contains(&name) {
                params.values.insert(name, f64::from(p.param_value));
            }
        }
        seen(&r);
    }
    Ok(params)
}

/// Sets the integer parameter `name` to `value` on the autopilot and waits until it says so: the
/// `PARAM_SET` is sent again every half second until a `PARAM_VALUE` of `name` reports `value`
/// or `timeout` passes. ArduPilot answers every `PARAM_SET` with the value it then holds (and
/// keeps it across reboots). Every message received meanwhile goes to `seen`.
///
/// Returns the value the autopilot last reported for `name` (`None`: no answer), which is
/// `value` when it took it.
///
/// # Errors
/// The link breaks.
pub fn write_param(
    link: &mut VehicleLink,
    autopilot: &Autopilot,
    name: &str,
    value: i32,
    timeout: Duration,
    mut seen: impl FnMut(&Received),
) -> Result<Option<f64>, LinkError> {
    let start = Instant::now();
    let mut next_ask = start;
    let mut reported = None;
    while reported != Some(f64::from(value)) && start.elapsed() < timeout {
        if Instant::now() >= next_ask {
            link.send(&MavMessage::PARAM_SET(PARAM_SET_DATA {
                param_value: value as f32,
                target_system: autopilot.system_id,
                target_component: autopilot.component_id,
                param_id: name.into(),
                // ArduPilot stores by its own type and converts; the ids set here are integers.
                param_type: MavParamType::MAV_PARAM_TYPE_INT32,
            }))?;
            next_ask = Instant::now() + RETRY;
        }
        let Some(r) = link.recv_timeout(Duration::from_millis(20))? else { continue };
        if let MavMessage::PARAM_VALUE(p) = &r.message
            && r.header.system_id == u32::from(autopilot.system_id)
            && param_name(p.param_id.as_slice()) == name
        {
            reported = Some(f64::from(p.param_value));
        }
        seen(&r);
    }
    Ok(reported)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_parameter_id_ends_at_its_first_nul_or_at_sixteen_characters() {
        let mut id = [0u8; 16];
        id[..15].copy_from_slice(b"SERVO1_FUNCTION");
        assert_eq!(param_name(&id), "SERVO1_FUNCTION");
        assert_eq!(param_name(b"COMPASS_AUTODEC_"), "COMPASS_AUTODEC_");
    }
}
