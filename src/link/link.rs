//! The MAVLink link to an autopilot: a receive thread that hands every message over a
//! channel, a ground-station heartbeat at 1 Hz (ArduSub's GCS failsafe disarms 5 s after the
//! last one), and the commands a controller sends (stream rates, arming, mode, the pilot
//! axes, per-output overrides), all from the configured ground-station system id (ArduSub
//! takes commands only from `SYSID_MYGCS`, 255 by default).

use super::signing::SigningKey;
use super::url::LinkAddress;
use mavlink::dialects::ardupilotmega::{
    COMMAND_LONG_DATA, HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MavAutopilot, MavCmd, MavMessage, MavModeFlag, MavState,
    MavType, RC_CHANNELS_OVERRIDE_DATA,
};
use mavlink::error::MessageReadError;
use mavlink::{Connectable, MavConnection, MavHeader};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

type Connection = mavlink::Connection<MavMessage>;

/// What to try where a connection was refused: the addresses BlueOS serves (its autopilot
/// manager's default endpoints), not the simulator's TCP 5760.
fn blueos_hint(source: &std::io::Error) -> &'static str {
    if source.kind() == std::io::ErrorKind::ConnectionRefused {
        "; nothing listens there. BlueOS serves MAVLink to a laptop on UDP (udpout:192.168.2.2:14550, its \
         \"GCS Server Link\") and to programs on the vehicle on tcp:127.0.0.1:5777; tcp:...:5760 is ArduSub's \
         simulator (docs/OWNER.md#connect)"
    } else {
        ""
    }
}

/// What can go wrong on the link.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The connection could not be opened (port in use, device missing, TCP refused).
    #[error("cannot open {address}: {source}{}", blueos_hint(.source))]
    Open {
        /// The address, in the crate's form.
        address: String,
        /// The cause.
        source: std::io::Error,
    },
    /// A message could not be sent.
    #[error("sending {message} on {address}: {detail}")]
    Send {
        /// The address.
        address: String,
        /// The message's name.
        message: &'static str,
        /// The cause.
        detail: String,
    },
    /// The connection broke (TCP closed, serial device gone).
    #[error("link {address} closed: {detail}")]
    Closed {
        /// The address.
        address: String,
        /// The cause.
        detail: String,
    },
    /// No autopilot heartbeat arrived in time.
    #[error(
        "no autopilot heartbeat on {address} within {timeout_s} s ({received} messages received{others}); is the vehicle on and the address right?"
    )]
    NoAutopilot {
        /// The address.
        address: String,
        /// The time waited (s).
        timeout_s: f64,
        /// Messages of any kind received meanwhile.
        received: u64,
        /// Which systems were heard, if any.
        others: String,
    },
}

/// Settings of the link.
#[derive(Debug, Clone)]
pub struct LinkConfig {
    /// System id pinc sends from: the autopilot's `SYSID_MYGCS` (255 by default in ArduSub).
    pub gcs_system_id: u8,
    /// Component id pinc sends from (190, `MAV_COMP_ID_MISSIONPLANNER`, as ground stations do).
    pub gcs_component_id: u8,
    /// Period of the ground-station heartbeat.
    pub heartbeat_period: Duration,
    /// How long one blocking read waits before the receive thread checks for a stop.
    pub read_timeout: Duration,
    /// MAVLink 2 signing: sign what is sent, drop what is not signed with this key.
    pub signing: Option<SigningKey>,
}

impl Default for LinkConfig {
    fn default() -> Self {
        Self {
            gcs_system_id: 255,
            gcs_component_id: 190,
            heartbeat_period: Duration::from_secs(1),
            read_timeout: Duration::from_millis(100),
            signing: None,
        }
    }
}

/// One message as received.
#[derive(Debug, Clone)]
pub struct Received {
    /// When the receive thread got it (host clock).
    pub at: Instant,
    /// Sender and sequence.
    pub header: MavHeader,
    /// The message.
    pub message: MavMessage,
}

/// The autopilot found by [`VehicleLink::wait_for_autopilot`].
#[derive(Debug, Clone)]
pub struct Autopilot {
    /// Its system id.
    pub system_id: u8,
    /// Its component id (1 for the autopilot).
    pub component_id: u8,
    /// Its first heartbeat.
    pub heartbeat: HEARTBEAT_DATA,
}

impl Autopilot {
    /// Whether this autopilot (its system and component) sent `r`.
    pub fn sent(&self, r: &Received) -> bool {
        r.header.system_id as u8 == self.system_id && r.header.component_id == self.component_id
    }

    /// Whether the heartbeat says armed.
    pub fn armed(heartbeat: &HEARTBEAT_DATA) -> bool {
        heartbeat.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED)
    }
}

/// ArduSub's flight modes (the heartbeat's `custom_mode`; ArduSub's `mode.h`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SubMode {
    /// Attitude stabilised, pilot throttle.
    Stabilize = 0,
    /// Rate control.
    Acro = 1,
    /// Depth hold.
    AltHold = 2,
    /// Mission.
    Auto = 3,
    /// Guided.
    Guided = 4,
    /// Circle.
    Circle = 7,
    /// Surface.
    Surface = 9,
    /// Position hold.
    PosHold = 16,
    /// Pilot axes straight to the mixer (no stabilisation): what pinc commands in.
    Manual = 19,
    /// Motor direction detection.
    MotorDetect = 20,
    /// Hold distance to the bottom.
    SurfTrak = 21,
}

impl SubMode {
    /// Every mode, for lookups.
    pub const ALL: [SubMode; 11] = [
        Self::Stabilize,
        Self::Acro,
        Self::AltHold,
        Self::Auto,
        Self::Guided,
        Self::Circle,
        Self::Surface,
        Self::PosHold,
        Self::Manual,
        Self::MotorDetect,
        Self::SurfTrak,
    ];

    /// The mode of a heartbeat's `custom_mode`, if ArduSub has it.
    pub fn from_custom_mode(mode: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|m| *m as u32 == mode)
    }

    /// The name ground stations show.
    pub fn name(self) -> &'static str {
        match self {
            Self::Stabilize => "STABILIZE",
            Self::Acro => "ACRO",
            Self::AltHold => "ALT_HOLD",
            Self::Auto => "AUTO",
            Self::Guided => "GUIDED",
            Self::Circle => "CIRCLE",
            Self::Surface => "SURFACE",
            Self::PosHold => "POSHOLD",
            Self::Manual => "MANUAL",
            Self::MotorDetect => "MOTOR_DETECT",
            Self::SurfTrak => "SURFTRAK",
        }
    }

    /// The name of a `custom_mode`, or `MODE_<n>` for one ArduSub does not have.
    pub fn name_of(mode: u32) -> String {
        Self::from_custom_mode(mode).map_or_else(|| format!("MODE_{mode}"), |m| m.name().to_string())
    }
}

/// Whether a heartbeat comes from a ground station (or another non-vehicle), not an autopilot.
pub fn is_ground_station(h: &HEARTBEAT_DATA) -> bool {
    h.mavtype == MavType::MAV_TYPE_GCS || h.autopilot == MavAutopilot::MAV_AUTOPILOT_INVALID
}

/// An open link. Dropping it stops the heartbeat and the receive thread (within one read
/// timeout; a serial read that never returns leaves its thread to end with the process).
pub struct VehicleLink {
    address: LinkAddress,
    config: LinkConfig,
    connection: Arc<Connection>,
    messages: Receiver<Result<Received, String>>,
    stop: Arc<AtomicBool>,
    target: Arc<Mutex<Option<(u8, u8)>>>,
    received: u64,
    /// Frames the crate could not parse (bad CRC, unknown id), counted by the receive thread.
    malformed: Arc<std::sync::atomic::AtomicU64>,
    threads: Vec<JoinHandle<()>>,
}

fn is_timeout(e: &std::io::Error) -> bool {
    matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut)
}

impl VehicleLink {
    /// Opens `address` and starts the receive thread and the ground-station heartbeat.
    ///
    /// # Errors
    /// The connection cannot be opened.
    pub fn connect(address: &LinkAddress, config: LinkConfig) -> Result<Self, LinkError> {
        let open = |source| LinkError::Open { address: address.to_string(), source };
        let connection = match address {
            // The crate's UDP reads block for ever without a timeout; the receive thread needs
            // one to notice a stop.
            LinkAddress::UdpIn(a) | LinkAddress::UdpOut(a) => {
                let mode = if matches!(address, LinkAddress::UdpIn(_)) {
                    mavlink::UdpMode::Udpin
                } else {
                    mavlink::UdpMode::Udpout
                };
                mavlink::UdpConfig::new(a.clone(), mode).read_timeout(config.read_timeout).connect::<MavMessage>()
            }
            LinkAddress::Serial { device, baud } => {
                mavlink::SerialConfig::new(device.clone(), *baud).timeout(config.read_timeout).connect::<MavMessage>()
            }
            other => {
                mavlink::ConnectionAddress::parse_address(&other.to_string()).and_then(|a| a.connect::<MavMessage>())
            }
        }
        .map_err(open)?;
        let mut connection = connection;
        connection.set_protocol_version(mavlink::MavlinkVersion::V2);
        connection.set_allow_recv_any_version(true);
        if let Some(key) = &config.signing {
            // Link id 0: one link per ground station, as ArduPilot numbers its own.
            connection.setup_signing(Some(key.config(0)));
        }
        let connection = Arc::new(connection);
        let stop = Arc::new(AtomicBool::new(false));
        let malformed = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let (tx, rx) = mpsc::channel();
        let receiver = {
            let (connection, stop, malformed) = (connection.clone(), stop.clone(), malformed.clone());
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    let item = match connection.recv() {
                        Ok((header, message)) => Ok(Received { at: Instant::now(), header, message }),
                        Err(MessageReadError::Io(e)) if is_timeout(&e) => continue,
                        Err(MessageReadError::Parse(_)) => {
                            malformed.fetch_add(1, Ordering::Relaxed);
                            continue;
                        }
                        Err(MessageReadError::Io(e)) => Err(e.to_string()),
                    };
                    let closed = item.is_err();
                    if tx.send(item).is_err() || closed {
                        break;
                    }
                }
            })
        };
        let link = Self {
            address: address.clone(),
            config,
            connection,
            messages: rx,
            stop,
            target: Arc::new(Mutex::new(None)),
            received: 0,
            malformed,
            threads: vec![receiver],
        };
        let heartbeat = {
            let (connection, stop, header, period) =
                (link.connection.clone(), link.stop.clone(), link.header(), link.config.heartbeat_period);
            std::thread::spawn(move || {
                let beat = MavMessage::HEARTBEAT(gcs_heartbeat());
                while !stop.load(Ordering::Relaxed) {
                    // A UDP listener has no peer until the first packet arrives; the crate then
                    // sends nothing, and the next beat tries again.
                    let _ = connection.send(&header, &beat);
                    let until = Instant::now() + period;
                    while Instant::now() < until && !stop.load(Ordering::Relaxed) {
                        std::thread::sleep(Duration::from_millis(20));
                    }
                }
            })
        };
        let mut link = link;
        link.threads.push(heartbeat);
        Ok(link)
    }

    /// The address this link was opened on.
    pub fn address(&self) -> &LinkAddress {
        &self.address
    }

    /// The system id pinc sends from.
    pub fn system_id(&self) -> u8 {
        self.config.gcs_system_id
    }

    /// The header pinc's messages go out with.
    fn header(&self) -> MavHeader {
        MavHeader {
            system_id: self.config.gcs_system_id.into(),
            component_id: self.config.gcs_component_id,
            sequence: 0,
        }
    }

    /// Messages received so far (by [`VehicleLink::recv_timeout`]).
    pub fn received(&self) -> u64 {
        self.received
    }

    /// Frames that could not be parsed so far (bad checksum, a message the dialect lacks).
    pub fn malformed(&self) -> u64 {
        self.malformed.load(Ordering::Relaxed)
    }

    /// The next message, or `None` when none arrives within `timeout`.
    ///
    /// # Errors
    /// The connection broke.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Result<Option<Received>, LinkError> {
        match self.messages.recv_timeout(timeout) {
            Ok(Ok(r)) => {
                self.received += 1;
                Ok(Some(r))
            }
            Ok(Err(detail)) => Err(LinkError::Closed { address: self.address.to_string(), detail }),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => {
                Err(LinkError::Closed { address: self.address.to_string(), detail: "receive thread ended".into() })
            }
        }
    }

    /// Waits for the first heartbeat of an autopilot (ground stations' heartbeats are
    /// skipped); commands go to it from then on. Every message received meanwhile is passed
    /// to `seen`.
    ///
    /// # Errors
    /// None arrives within `timeout`, or the connection broke.
    pub fn wait_for_autopilot(
        &mut self,
        timeout: Duration,
        mut seen: impl FnMut(&Received),
    ) -> Result<Autopilot, LinkError> {
        let start = Instant::now();
        let mut others = std::collections::BTreeSet::new();
        loop {
            let left = timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                let mut others = if others.is_empty() {
                    String::new()
                } else {
                    let list: Vec<String> = others.iter().map(|(s, c)| format!("{s}/{c}")).collect();
                    format!(", none an autopilot's heartbeat; heard system/component {}", list.join(", "))
                };
                if let Some(key) = &self.config.signing {
                    others.push_str(&format!(
                        "; signing is on (key {}): frames not signed with that key are dropped, so an autopilot \
                         without signing or set up with another key is not heard",
                        key.source()
                    ));
                }
                return Err(LinkError::NoAutopilot {
                    address: self.address.to_string(),
                    timeout_s: timeout.as_secs_f64(),
                    received: self.received,
                    others,
                });
            }
            let Some(r) = self.recv_timeout(left.min(Duration::from_millis(100)))? else { continue };
            seen(&r);
            let (system_id, component_id) = (r.header.system_id as u8, r.header.component_id);
            match &r.message {
                MavMessage::HEARTBEAT(h) if !is_ground_station(h) => {
                    *self.target.lock().expect("target lock") = Some((system_id, component_id));
                    return Ok(Autopilot { system_id, component_id, heartbeat: h.clone() });
                }
                _ => {
                    others.insert((system_id, component_id));
                }
            }
        }
    }

    /// The autopilot's system and component ids (1, 1 before one was found).
    fn target(&self) -> (u8, u8) {
        self.target.lock().expect("target lock").unwrap_or((1, 1))
    }

    /// Sends one message from the ground-station ids.
    ///
    /// # Errors
    /// Writing fails.
    pub fn send(&self, message: &MavMessage) -> Result<(), LinkError> {
        self.connection.send(&self.header(), message).map(|_| ()).map_err(|e| LinkError::Send {
            address: self.address.to_string(),
            message: mavlink::Message::message_name(message),
            detail: e.to_string(),
        })
    }

    /// A `COMMAND_LONG` to the autopilot.
    ///
    /// # Errors
    /// Writing fails.
    pub fn command(&self, command: MavCmd, params: [f32; 7]) -> Result<(), LinkError> {
        let (target_system, target_component) = self.target();
        let [param1, param2, param3, param4, param5, param6, param7] = params;
        self.send(&MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            param1,
            param2,
            param3,
            param4,
            param5,
            param6,
            param7,
            command,
            target_system,
            target_component,
            confirmation: 0,
        }))
    }

    /// Asks for message `id` every `1 / rate_hz` s (`MAV_CMD_SET_MESSAGE_INTERVAL`); a rate of
    /// 0 stops it.
    ///
    /// # Errors
    /// Writing fails.
    pub fn set_message_rate(&self, id: u32, rate_hz: f64) -> Result<(), LinkError> {
        let interval_us = if rate_hz > 0.0 { (1e6 / rate_hz).round() as f32 } else { -1.0 };
        self.command(MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL, [id as f32, interval_us, 0.0, 0.0, 0.0, 0.0, 0.0])
    }

    /// Asks for message `id` once (`MAV_CMD_REQUEST_MESSAGE`), e.g. `AUTOPILOT_VERSION` (148).
    ///
    /// # Errors
    /// Writing fails.
    pub fn request_message(&self, id: u32) -> Result<(), LinkError> {
        self.command(MavCmd::MAV_CMD_REQUEST_MESSAGE, [id as f32, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    }

    /// Asks for the messages the state is built from, at `rate_hz` each: `ATTITUDE`,
    /// `LOCAL_POSITION_NED`, `SCALED_PRESSURE`, `SCALED_PRESSURE2` and `SERVO_OUTPUT_RAW`.
    ///
    /// # Errors
    /// Writing fails.
    pub fn request_state_streams(&self, rate_hz: f64) -> Result<(), LinkError> {
        for id in STATE_MESSAGE_IDS {
            self.set_message_rate(id, rate_hz)?;
        }
        Ok(())
    }

    /// Arms (`true`) or disarms the vehicle (`MAV_CMD_COMPONENT_ARM_DISARM`).
    ///
    /// # Errors
    /// Writing fails.
    pub fn arm(&self, arm: bool) -> Result<(), LinkError> {
        self.command(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, [f32::from(u8::from(arm)), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    }

    /// Switches the flight mode (`MAV_CMD_DO_SET_MODE` with a custom mode).
    ///
    /// # Errors
    /// Writing fails.
    pub fn set_mode(&self, mode: SubMode) -> Result<(), LinkError> {
        let custom = f32::from(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits());
        self.command(MavCmd::MAV_CMD_DO_SET_MODE, [custom, mode as u32 as f32, 0.0, 0.0, 0.0, 0.0, 0.0])
    }

    /// The four pilot axes (`MANUAL_CONTROL`): `x` forward, `y` right, `r` yaw right in
    /// -1000..=1000, `z` 0..=1000 with 500 neutral and above 500 up (ArduSub's convention).
    ///
    /// # Errors
    /// Writing fails.
    pub fn manual_control(&self, x: i16, y: i16, z: i16, r: i16) -> Result<(), LinkError> {
        let (target, _) = self.target();
        self.send(&MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA { x, y, z, r, buttons: 0, target }))
    }

    /// `RC_CHANNELS_OVERRIDE` of channels 1-8 (PWM in us; 0 releases a channel, `u16::MAX`
    /// leaves it unchanged, as MAVLink defines).
    ///
    /// # Errors
    /// Writing fails.
    pub fn rc_override(&self, channels: [u16; 8]) -> Result<(), LinkError> {
        let (target_system, target_component) = self.target();
        let [chan1_raw, chan2_raw, chan3_raw, chan4_raw, chan5_raw, chan6_raw, chan7_raw, chan8_raw] = channels;
        self.send(&MavMessage::RC_CHANNELS_OVERRIDE(RC_CHANNELS_OVERRIDE_DATA {
            chan1_raw,
            chan2_raw,
            chan3_raw,
            chan4_raw,
            chan5_raw,
            chan6_raw,
            chan7_raw,
            chan8_raw,
            target_system,
            target_component,
        }))
    }
}

/// Ids of the messages [`VehicleLink::request_state_streams`] asks for: `ATTITUDE` (30),
/// `LOCAL_POSITION_NED` (32), `SCALED_PRESSURE` (29), `SCALED_PRESSURE2` (137),
/// `SERVO_OUTPUT_RAW` (36), `GLOBAL_POSITION_INT` (33, for its vertical velocity).
pub const STATE_MESSAGE_IDS: [u32; 6] = [30, 32, 29, 137, 36, 33];

/// Id of `AUTOPILOT_VERSION`.
pub const AUTOPILOT_VERSION_ID: u32 = 148;

/// Id of `EKF_STATUS_REPORT`: the autopilot's word on its own estimate.
pub const EKF_STATUS_REPORT_ID: u32 = 193;

/// Id of `GPS_RAW_INT`: its fix says when a GPS position source is lost.
pub const GPS_RAW_INT_ID: u32 = 24;

/// Id of `SYS_STATUS`: its sensor health says when a DVL (visual odometry) stops.
pub const SYS_STATUS_ID: u32 = 1;

/// The heartbeat of a ground station.
fn gcs_heartbeat() -> HEARTBEAT_DATA {
    HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_GCS,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    }
}

impl Drop for VehicleLink {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        // The heartbeat thread ends within 20 ms; the receive thread within one read timeout
        // unless its transport blocks for ever (serial), so it is not joined.
        if let Some(h) = self.threads.pop() {
            let _ = h.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::ardupilotmega::ATTITUDE_DATA;

    fn free_port() -> u16 {
        std::net::UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
    }

    /// An autopilot on a loopback socket: pinc listens, the autopilot sends to it.
    #[test]
    fn link_finds_the_autopilot_and_commands_come_from_the_gcs_ids() {
        let port = free_port();
        let address: LinkAddress = format!("udpin:127.0.0.1:{port}").parse().unwrap();
        let mut link = VehicleLink::connect(&address, LinkConfig { gcs_system_id: 254, ..LinkConfig::default() })
            .expect("listen on a free port");
        let autopilot = mavlink::connect::<MavMessage>(&format!("udpout:127.0.0.1:{port}")).unwrap();
        let ap = MavHeader { system_id: 7, component_id: 1, sequence: 0 };
        let gcs = MavHeader { system_id: 200, component_id: 190, sequence: 0 };
        let sub = HEARTBEAT_DATA {
            custom_mode: SubMode::Manual as u32,
            mavtype: MavType::MAV_TYPE_SUBMARINE,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            base_mode: MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED | MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        };
        // Another ground station's heartbeat and an attitude come first: neither is the autopilot.
        autopilot.send(&gcs, &MavMessage::HEARTBEAT(gcs_heartbeat())).unwrap();
        autopilot.send(&ap, &MavMessage::ATTITUDE(ATTITUDE_DATA::default())).unwrap();
        autopilot.send(&ap, &MavMessage::HEARTBEAT(sub.clone())).unwrap();
        let mut seen = Vec::new();
        let found = link.wait_for_autopilot(Duration::from_secs(5), |r| seen.push(r.header.system_id)).unwrap();
        assert_eq!((found.system_id, found.component_id), (7, 1));
        assert!(Autopilot::armed(&found.heartbeat));
        assert_eq!(seen, [200, 7, 7]);
        // The link now knows where to send: a stream request and an arm command reach the
        // autopilot from system 254, addressed to system 7.
        link.set_message_rate(30, 12.5).unwrap();
        link.arm(true).unwrap();
        let mut commands = Vec::new();
        let mut heartbeat_from_gcs = false;
        let deadline = Instant::now() + Duration::from_secs(5);
        while commands.len() < 2 && Instant::now() < deadline {
            let (h, m) = autopilot.recv().unwrap();
            assert_eq!((h.system_id, h.component_id), (254, 190));
            match m {
                MavMessage::COMMAND_LONG(c) => commands.push(c),
                MavMessage::HEARTBEAT(b) => heartbeat_from_gcs |= is_ground_station(&b),
                _ => {}
            }
        }
        assert_eq!(commands.len(), 2);
        let rate = &commands[0];
        assert_eq!(
            (rate.command, rate.target_system, rate.target_component),
            (MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL, 7, 1)
        );
        assert_eq!((rate.param1, rate.param2), (30.0, 80_000.0));
        assert_eq!((commands[1].command, commands[1].param1), (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 1.0));
        // The 1 Hz ground-station heartbeat flows too (its first beat may precede the peer).
        let deadline = Instant::now() + Duration::from_secs(3);
        while !heartbeat_from_gcs && Instant::now() < deadline {
            if let Ok((_, MavMessage::HEARTBEAT(b))) = autopilot.recv() {
                heartbeat_from_gcs = is_ground_station(&b);
            }
        }
        assert!(heartbeat_from_gcs);
    }

    #[test]
    fn no_autopilot_is_a_timeout_naming_the_address() {
        let address: LinkAddress = format!("udpin:127.0.0.1:{}", free_port()).parse().unwrap();
        let mut link = VehicleLink::connect(&address, LinkConfig::default()).unwrap();
        let e = link.wait_for_autopilot(Duration::from_millis(300), |_| {}).unwrap_err();
        assert!(matches!(e, LinkError::NoAutopilot { received: 0, .. }), "{e}");
        assert!(e.to_string().contains(&address.to_string()), "{e}");
    }

    #[test]
    fn ardusub_modes_round_trip_by_number() {
        for m in SubMode::ALL {
            assert_eq!(SubMode::from_custom_mode(m as u32), Some(m));
        }
        assert_eq!(SubMode::name_of(19), "MANUAL");
        assert_eq!(SubMode::name_of(2), "ALT_HOLD");
        assert_eq!(SubMode::name_of(5), "MODE_5");
    }
}
