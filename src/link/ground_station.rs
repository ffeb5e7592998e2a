//! The autopilot's one ground station: ArduSub takes pilot axes (`MANUAL_CONTROL`,
//! `RC_CHANNELS_OVERRIDE`) only from the system id its parameter names (`MAV_GCS_SYSID` in
//! newer ArduPilot, this firmware's 4.8 among them, `SYSID_MYGCS` before), and two senders under
//! that id take turns on the thrusters (measured: python/tests/test_ardusub_pilot.py). To fly a
//! ground station's joystick (Cockpit's) as its sticks, pinc takes that station's place for the
//! flight, so the autopilot obeys pinc alone while pinc reads the joystick's messages on its
//! link, and gives the place back at the stop.

use super::link::{Autopilot, LinkError, Received, VehicleLink};
use super::params::{Params, read_params, write_param};
use super::safety::Trigger;
use std::time::Duration;

/// The parameter's names, newest first.
const NAMES: [&str; 2] = ["MAV_GCS_SYSID", "SYSID_MYGCS"];
/// The top of a range of ground-station ids (newer ArduPilot): at or above `MAV_GCS_SYSID` every
/// id from one to the other is a ground station.
const RANGE_TOP: &str = "MAV_GCS_SYSID_HI";
/// MAVLink options (newer ArduPilot): bit 0, accept MAVLink only from the ground stations.
const OPTIONS: &str = "MAV_OPTIONS";
/// How long reading or setting them may take: ArduSub answers within 0.35 s, the requests are
/// repeated every half second, and a name the firmware does not have is never answered.
const TIMEOUT: Duration = Duration::from_millis(1500);

/// The place pinc holds: which parameter, and the id it goes back to.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundStationPlace {
    name: &'static str,
    restore: u8,
}

impl GroundStationPlace {
    /// Sets the autopilot's ground station to pinc's own id (the link's) in place of `ground`,
    /// after checking that this leaves `ground` out: a range of ground stations that would
    /// still hold it, or an autopilot that would then refuse `ground`'s every message, is
    /// refused. Every message received meanwhile goes to `seen`.
    ///
    /// Returns the place (to give back) and what was done, in words.
    ///
    /// # Errors
    /// The refusal, with the place to give back if the parameter may have been changed.
    pub fn take(
        link: &mut VehicleLink,
        autopilot: &Autopilot,
        ground: u8,
        mut seen: impl FnMut(&Received),
    ) -> Result<(Self, String), (Option<Self>, Trigger)> {
        let own = link.system_id();
        let refused = |why: String| (None, Trigger::Refused(why));
        if own == ground {
            return Err(refused(format!(
                "the pilot's ground station and pinc both send as system {own}: give pinc another --gcs-sysid"
            )));
        }
        let params = read(link, autopilot, &[RANGE_TOP, OPTIONS], &mut seen).map_err(|e| link_lost(None, e))?;
        let Some((name, found)) = answered(&params) else {
            return Err(refused(format!(
                "the autopilot answered neither {} nor {} within {:.1} s: pinc cannot take the ground station's place",
                NAMES[0],
                NAMES[1],
                TIMEOUT.as_secs_f64()
            )));
        };
        if let Some(top) = params.get(RANGE_TOP)
            && (f64::from(own)..=top).contains(&f64::from(ground))
        {
            return Err(refused(format!(
                "{RANGE_TOP} = {top}: with {name} = {own} the autopilot would still take system {ground}'s pilot \
                 axes (a range of ground stations); give pinc a --gcs-sysid above {ground}, or lower {RANGE_TOP}"
            )));
        }
        if params.get(OPTIONS).is_some_and(|o| (o as u32) & 1 == 1) {
            return Err(refused(format!(
                "{OPTIONS} bit 0 is set: with {name} = {own} the autopilot would ignore every message of system \
                 {ground}, its disarm and mode commands too"
            )));
        }
        // What goes back: what was there, unless an earlier session left pinc's own id.
        let restore = if found == f64::from(own) || !(1.0..=255.0).contains(&found) { ground } else { found as u8 };
        let place = Self { name, restore };
        let reported = write_param(link, autopilot, name, i32::from(own), TIMEOUT, &mut seen)
            .map_err(|e| link_lost(Some(place.clone()), e))?;
        if reported != Some(f64::from(own)) {
            let reported = reported.map_or("nothing".into(), |v| v.to_string());
            return Err((
                Some(place),
                Trigger::Refused(format!(
                    "the autopilot did not take {name} = {own} within {:.1} s (it reports {reported})",
                    TIMEOUT.as_secs_f64()
                )),
            ));
        }
        let said = format!(
            "{name} = {own} (pinc; it was {found}): the autopilot ignores system {ground}'s pilot axes, which pinc \
             reads as the sticks; {name} goes back to {restore} at the stop"
        );
        Ok((place, said))
    }

    /// Gives the place back (after the stop's neutral and disarm).
    ///
    /// # Errors
    /// Not confirmed by the autopilot: what to do, in words (a place not given back leaves
    /// the ground station's joystick ignored).
    pub fn give_back(&self, link: &mut VehicleLink, autopilot: &Autopilot) -> Result<String, String> {
        let Self { name, restore } = self;
        match write_param(link, autopilot, name, i32::from(*restore), TIMEOUT, |_| {}) {
            Ok(Some(v)) if v == f64::from(*restore) => {
                Ok(format!("{name} = {restore} again: the autopilot takes system {restore}'s pilot axes"))
            }
            reported => {
                let why = match reported {
                    Ok(Some(v)) => format!("it reports {v}"),
                    Ok(None) => "no answer".into(),
                    Err(e) => e.to_string(),
                };
                Err(format!(
                    "{name} could not be set back to {restore} ({why}): the autopilot ignores system {restore}'s \
                     joystick until {name} is {restore} again (set it in the ground station's parameters; the \
                     next pinc flight on the joystick sets it back at its stop)"
                ))
            }
        }
    }
}

/// Gives the place back where a flight on a joystick left it, killed before its stop (with
/// its server, or the autopilot rebooting under it): the autopilot's ground station is still
/// `left` (the flight's id), and goes back to `ground`. `None`: nothing left (or no answer).
/// Every message received meanwhile goes to `seen`; `still_free` is asked just before the
/// write (a flight started meanwhile keeps its place).
pub fn give_back_left_place(
    link: &mut VehicleLink,
    autopilot: &Autopilot,
    left: u8,
    ground: u8,
    mut seen: impl FnMut(&Received),
    still_free: impl Fn() -> bool,
) -> Option<Result<String, String>> {
    let params = match read(link, autopilot, &[], &mut seen) {
        Ok(p) => p,
        Err(e) => return Some(Err(e.to_string())),
    };
    let (name, found) = answered(&params)?;
    if found != f64::from(left) || !still_free() {
        return None;
    }
    let place = GroundStationPlace { name, restore: ground };
    Some(place.give_back(link, autopilot).map(|said| format!("a flight on the joystick left {name} = {left}: {said}")))
}

/// The ground-station parameter under both its names, and `more`.
fn read(
    link: &mut VehicleLink,
    autopilot: &Autopilot,
    more: &[&str],
    seen: impl FnMut(&Received),
) -> Result<Params, LinkError> {
    let names: Vec<String> = NAMES.iter().chain(more).map(|n| n.to_string()).collect();
    read_params(link, autopilot, &names, TIMEOUT, seen)
}

/// The name the autopilot answered to, and its value.
fn answered(params: &Params) -> Option<(&'static str, f64)> {
    NAMES.iter().find_map(|n| params.get(n).map(|v| (*n, v)))
}

fn link_lost(place: Option<GroundStationPlace>, e: LinkError) -> (Option<GroundStationPlace>, Trigger) {
    (place, Trigger::Link(e.to_string()))
}
